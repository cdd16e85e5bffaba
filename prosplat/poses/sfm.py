"""Photos without poses become a posed set: pycolmap's SIFT, matching and incremental mapping.

:func:`estimate_poses` runs the classical structure-from-motion chain on the CPU, in phases
that each report ``(phase, done, total)``:

* ``frames`` (a video only): the sharpest frame of each interval (:mod:`.video`);
* ``prepare``: an upright, bounded working copy of every photo (:mod:`.photos`); unreadable
  files are named and skipped;
* ``extract``: SIFT features, at most ``feature_size`` px and ``max_features`` per photo;
  photos that share a camera (same size, make, model and focal length) share its
  intrinsics, which the mapper then fits from all of them;
* ``match``: exhaustive for small sets, sequential (each photo with its next ten) for
  video frames and large sets;
* ``map``: incremental mapping; the largest model wins, and photos outside it are reported
  as not registered;
* ``write``: the model is made upright (:mod:`.frame`) and written as a pose folder
  (``images/``, ``sparse/0``, ``transforms.json``, ``poses.json``, ``database.db``).

pycolmap reports no counts while it extracts or matches: extraction runs in batches of
photos (about :data:`BATCHES` calls, the bar moving after each); matching runs a first call
of :data:`RATE_PAIRS` pairs, timed, and the rest in one call while the bar moves at that
rate. The mapper's per-image callback counts registered photos. Nothing reads
the database while pycolmap writes it: a second SQLite in the process (Python's ``sqlite3``)
shares the process's POSIX locks with pycolmap's own, and reading through it crashed a
30-photo run (SIGBUS in COLMAP's WAL checkpoint). A helper thread polls ``cancel`` and trips
a pycolmap ``CancellationToken``, so a long phase stops within a fraction of a second.

Resume: the working copies and the database live in a hidden sibling ``.OUT.poses-work/``
while the command runs. An interrupted or failed run leaves it, and the next run reuses it
(copies whose source is unchanged are kept; COLMAP skips photos whose features are in the
database and pairs already matched). Success moves the database into ``OUT`` and deletes the
work folder; a re-run into an existing pose folder (``overwrite``) starts from its database.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

try:
    import pycolmap
except ImportError:  # a training-only machine: estimate_poses says what to install
    pycolmap = None

from prosplat.convert.colmap import read_colmap_model
from prosplat.convert.distortion import Distortion
from prosplat.convert.nerfstudio import Frame, write_transforms
from prosplat.core.camera import Camera
from prosplat.core.paths import staged_folder, write_text_atomic
from prosplat.poses.errors import PoseCancelled, PoseError, require
from prosplat.poses.frame import near_far, upright_similarity
from prosplat.poses.photos import Photo, list_photos, working_names, write_working_copy
from prosplat.poses.video import extract_frames, is_video

__all__ = [
    "DATABASE",
    "PHASES",
    "PHASE_LABELS",
    "PHASE_UNITS",
    "POSES_JSON",
    "PoseOptions",
    "PoseResult",
    "estimate_poses",
    "load_pose_result",
    "quiet_colmap",
    "reusable",
    "source_record",
    "work_folder",
]

PHASES = ("frames", "prepare", "extract", "match", "map", "write")
#: what each phase is called where people see it (the command line's bars, the add-on's
#: status bar), and what it counts
PHASE_LABELS = {
    "frames": "extracting video frames",
    "prepare": "reading photos",
    "extract": "finding features",
    "match": "matching photos",
    "map": "solving camera poses",
    "write": "writing the pose folder",
}
PHASE_UNITS = {"frames": "frame", "match": "pair", "write": "step"}  # else "photo"
POSES_JSON = "poses.json"
DATABASE = "database.db"
MANIFEST = "prepare.json"  # in the work folder: the copies made so far and their sources
SEQUENTIAL_ABOVE = 60  # "auto" matching: sequential for more photos than this
SEQUENTIAL_OVERLAP = 10  # sequential matching: each photo with its next ten (and 2^k-th)
BATCHES = 20  # extraction runs in about this many pycolmap calls (the bar's steps)
RATE_PAIRS = 100  # matching: pairs of the first, timed call; the rest go in one more call
POLL_SECONDS = 0.25
CAMERA_MODEL = "SIMPLE_RADIAL"  # one focal, centred principal point, one radial term
FALLBACK_NEAR_FAR = (0.1, 20.0)  # a model with too few points for a depth range (rare)
_MATCHING = ("auto", "exhaustive", "sequential")
SHORT_LIST = 8  # names of unregistered photos in the failure line, at most
CANCELLED = "cancelled; nothing was written (a re-run resumes the work)"


@dataclass
class PoseOptions:
    """How :func:`estimate_poses` works; the defaults suit 10-60 photos on a laptop CPU."""

    feature_size: int = 1024  # longest side SIFT sees (pycolmap max_image_size)
    image_size: int = 1600  # longest side of the working copies the poses refer to
    max_features: int = 4096
    matching: str = "auto"  # "auto" | "exhaustive" | "sequential"
    single_camera: bool | None = None  # None: one camera per (size, make, model, focal)
    max_frames: int = 60  # video only
    seed: int = 0

    def __post_init__(self) -> None:
        if self.matching not in _MATCHING:
            raise ValueError(f"matching must be one of {_MATCHING}, got {self.matching!r}")
        for name in ("feature_size", "image_size", "max_features", "max_frames"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass
class PoseResult:
    """A finished pose folder (see :func:`estimate_poses`)."""

    folder: Path  # the pose folder
    names: list[str]  # registered photos (working-copy file names, in input order)
    cameras: list[Camera]  # per registered photo, in the upright frame (distorted intrinsics)
    unregistered: list[str]  # photos that were read but not registered
    skipped: list[tuple[str, str]]  # (file, reason): unreadable photos
    points: np.ndarray  # [N,3] float32 SfM points, upright frame
    near: float
    far: float
    reprojection_error: float  # mean, pixels
    timings: dict[str, float]  # seconds per phase: prepare, extract, match, map, write
    distortions: list[Distortion | None] = field(default_factory=list)  # lens per camera
    sources: dict[str, str] = field(default_factory=dict)  # working-copy name -> source file


def quiet_colmap(quiet: bool = True) -> None:
    """Keep COLMAP's own log (a line per step, on stderr) to errors only, or let it speak
    again. The command line and the worker call it: their bars and reports say the same in
    fewer lines. Process-wide (COLMAP's logger is global), so a library call leaves it be."""
    if pycolmap is not None:  # without it no pose step runs (estimate_poses says so)
        pycolmap.logging.minloglevel = 2 if quiet else 0


def work_folder(out: str | Path) -> Path:
    """The hidden sibling of ``out`` that holds an unfinished run's copies and database."""
    out = Path(out)
    return out.with_name(f".{out.name}.poses-work")


# ---- progress and cancel ----------------------------------------------------------------
class _Watch:
    """A helper thread that trips pycolmap's token when ``cancel()`` says so (pycolmap's
    calls block for seconds to minutes), and the phases' progress reports (from pycolmap's
    mapper thread too: calls never overlap)."""

    def __init__(
        self,
        progress: Callable[[str, int, int], None] | None,
        cancel: Callable[[], bool] | None,
    ) -> None:
        self.token = pycolmap.CancellationToken()
        self._progress = progress
        self._cancel = cancel
        self._lock = threading.Lock()
        self._last: tuple[str, int, int] | None = None
        self._pace: tuple[str, int, int, float, float] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="prosplat-poses-watch", daemon=True)

    def __enter__(self) -> _Watch:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def cancelled(self) -> bool:
        if not self.token.is_cancelled and self._cancel is not None and self._cancel():
            self.token.cancel()
        return bool(self.token.is_cancelled)

    def check(self) -> None:
        """Raise :class:`PoseCancelled` when cancel was asked for."""
        if self.cancelled():
            raise PoseCancelled(CANCELLED)

    @contextmanager
    def stoppable(self) -> Iterator[None]:
        """Around a pycolmap call: its ``InterruptedError`` (the token tripped) is a cancel."""
        try:
            yield
        except InterruptedError:
            raise PoseCancelled(CANCELLED) from None

    def report(self, phase: str, done: int, total: int) -> None:
        item = (phase, int(min(done, total)), int(total))
        with self._lock:
            if self._progress is None or item == self._last:
                return
            self._last = item
            self._progress(*item)

    @contextmanager
    def paced(self, phase: str, done: int, total: int, seconds_per_step: float) -> Iterator[None]:
        """Around one long pycolmap call that reports nothing: the bar moves from ``done`` at
        the measured rate, short of ``total`` until the call returns (an estimate, never a
        count the database was read for: see the module docstring)."""
        self._pace = (phase, done, total, seconds_per_step, time.perf_counter())
        try:
            yield
        finally:
            self._pace = None

    def _run(self) -> None:
        while not self._stop.wait(POLL_SECONDS):
            try:
                self.cancelled()
                pace = self._pace
                if pace is not None:
                    phase, done, total, rate, start = pace
                    guess = done + int((time.perf_counter() - start) / rate)
                    self.report(phase, min(guess, total - 1), total)
            except Exception:  # a callback's failure must not kill the watch
                pass


# ---- inputs -----------------------------------------------------------------------------
def _source_files(source: Path | Sequence[Path]) -> list[Path]:
    if isinstance(source, (str, os.PathLike)):
        folder = Path(source)
        if not folder.exists():
            raise PoseError(f"{folder} does not exist; give a folder of photos or a video")
        if folder.is_file():
            raise PoseError(
                f"{folder} is neither a folder of photos nor a video (mp4 mov m4v avi mkv webm)"
            )
        files = list_photos(folder)
        if not files:
            raise PoseError(f"{folder} holds no photos (jpg, png, exr, tif, webp)")
        return files
    files = [Path(p) for p in source]
    missing = [str(p) for p in files if not p.is_file()]
    if missing:
        raise PoseError(
            f"photo not found: {missing[0]}"
            + (f" (+{len(missing) - 1} more)" if len(missing) > 1 else "")
        )
    return files


def _stat(path: Path) -> dict:
    st = path.stat()
    return {"path": str(path.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _seed_work(out: Path, work: Path) -> None:
    """Start a re-run into a finished pose folder from its copies and database."""
    try:
        report = json.loads((out / POSES_JSON).read_text())
    except (OSError, ValueError):
        return
    (work / "images").mkdir(parents=True, exist_ok=True)
    photos = {}
    for entry in report.get("photos", []):
        src = out / "images" / entry["name"]
        if src.is_file():
            shutil.copy2(src, work / "images" / entry["name"])
            photos[entry["path"]] = entry
    if (out / DATABASE).is_file():
        shutil.copy2(out / DATABASE, work / DATABASE)
    manifest = {"features": report.get("features"), "photos": photos}
    write_text_atomic(work / MANIFEST, json.dumps(manifest))


def _prepare(
    files: list[Path], work: Path, options: PoseOptions, watch: _Watch
) -> tuple[list[Photo], list[tuple[str, str]], dict]:
    """Working copies in ``work/images`` (reusing unchanged ones), the files skipped, and the
    manifest (written to ``work/prepare.json`` as it goes)."""
    images = work / "images"
    images.mkdir(parents=True, exist_ok=True)
    try:
        old = json.loads((work / MANIFEST).read_text())
    except (OSError, ValueError):
        old = {}
    features = {
        "image_size": options.image_size,
        "feature_size": options.feature_size,
        "max_features": options.max_features,
    }
    if old.get("features") != features:  # other copies or features: start afresh
        old = {}
        (work / DATABASE).unlink(missing_ok=True)
    kept = old.get("photos", {})
    photos: list[Photo] = []
    skipped: list[tuple[str, str]] = []
    entries: dict[str, dict] = {}
    names = working_names(files)
    watch.report("prepare", 0, len(files))
    for i, (src, name) in enumerate(zip(files, names, strict=True)):
        watch.check()
        stat = _stat(src)
        prev = kept.get(stat["path"])
        dst = images / name
        if (
            prev is not None
            and prev.get("name") == name
            and prev.get("size") == stat["size"]
            and prev.get("mtime_ns") == stat["mtime_ns"]
            and dst.is_file()
        ):
            photo = Photo(src, name, prev["width"], prev["height"], tuple(prev["camera_key"]))
        else:
            try:
                photo = write_working_copy(src, dst, options.image_size)
            except ValueError as e:
                skipped.append((str(src), str(e).split(": ", 1)[-1]))
                watch.report("prepare", i + 1, len(files))
                continue
        photos.append(photo)
        entries[stat["path"]] = {
            **stat,
            "name": name,
            "width": photo.width,
            "height": photo.height,
            "camera_key": list(photo.camera_key),
        }
        watch.report("prepare", i + 1, len(files))
    wanted = {p.name for p in photos}
    for stale in images.iterdir():
        if stale.name not in wanted:
            stale.unlink()
    manifest = {"features": features, "photos": entries}
    write_text_atomic(work / MANIFEST, json.dumps(manifest))
    return photos, skipped, manifest


def _camera_groups(photos: list[Photo], single: bool | None) -> list[list[Photo]]:
    """Photos that share one camera: all (single), none (False), or same key (None); one
    camera never spans two image sizes."""
    groups: dict[tuple, list[Photo]] = {}
    for i, p in enumerate(photos):
        if single is False:
            key: tuple = (i,)
        elif single:
            key = (p.width, p.height)
        else:
            key = p.camera_key
        groups.setdefault(key, []).append(p)
    return list(groups.values())


def _check_database(db: Path, names: list[str]) -> dict[str, int]:
    """Image name -> camera id of the photos already in the database; a database holding
    other photos (another set, or copies since deleted) is removed, so it never leaks in."""
    if not db.is_file():
        return {}
    try:
        database = pycolmap.Database.open(str(db))
        try:
            known = {im.name: int(im.camera_id) for im in database.read_all_images()}
        finally:
            database.close()
    except Exception:  # unreadable (a kill mid-write): features are cheap to redo
        known = None
    if known is None or not set(known) <= set(names):
        db.unlink(missing_ok=True)
        return {}
    return known


# ---- the phases -------------------------------------------------------------------------
def _batches(items: list, count: int, least: int = 1) -> list[list]:
    """``items`` in about ``count`` consecutive batches of at least ``least`` each."""
    size = max(least, math.ceil(len(items) / max(count, 1)))
    return [items[i : i + size] for i in range(0, len(items), size)]


def _camera_ids(db: Path) -> dict[str, int]:
    """Image name -> camera id in the database (read between pycolmap calls, never during)."""
    database = pycolmap.Database.open(str(db))
    try:
        return {im.name: int(im.camera_id) for im in database.read_all_images()}
    finally:
        database.close()


def _extract(
    db: Path, images: Path, photos: list[Photo], options: PoseOptions, watch: _Watch
) -> None:
    """SIFT features of every photo not yet in the database, a batch of photos per call."""
    known = _check_database(db, [p.name for p in photos])
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = options.feature_size
    extraction.sift.max_num_features = options.max_features
    extraction.num_threads = -1
    done = 0
    watch.report("extract", 0, len(photos))
    for group in _camera_groups(photos, options.single_camera):
        # SIFT runs a photo per thread: a batch keeps every core busy
        for batch in _batches(group, BATCHES, 2 * (os.cpu_count() or 1)):
            watch.check()
            reader = pycolmap.ImageReaderOptions()
            reader.camera_model = CAMERA_MODEL
            ids = [known[p.name] for p in group if p.name in known]
            if ids:  # photos of this camera are in the database: the others join its camera
                reader.existing_camera_id = ids[0]
            mode = pycolmap.CameraMode.SINGLE if len(group) > 1 else pycolmap.CameraMode.PER_IMAGE
            with watch.stoppable():
                pycolmap.extract_features(
                    str(db),
                    str(images),
                    [p.name for p in batch],
                    mode,
                    reader,
                    extraction,
                    pycolmap.Device.cpu,
                    watch.token,
                )
            known = _camera_ids(db)
            done += len(batch)
            watch.report("extract", done, len(photos))
    watch.check()


def _pairs(names: list[str], sequential: bool, overlap: int = SEQUENTIAL_OVERLAP) -> list:
    """The pairs to match: every pair, or (sequential, as COLMAP's sequential matcher forms
    them) each photo with its next ``overlap`` photos and, the quadratic part, its 2^k-th."""
    n = len(names)
    if not sequential:
        return [(names[i], names[j]) for i in range(n) for j in range(i + 1, n)]
    pairs = set()
    for i in range(n):
        for k in range(overlap):
            for j in (i + k + 1, i + 2**k):
                if i < j < n:
                    pairs.add((i, j))
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def _match(db: Path, work: Path, names: list[str], sequential: bool, watch: _Watch) -> None:
    """Match and verify the pairs (:func:`_pairs`); pairs already in the database (a resumed
    run) are skipped by COLMAP.

    In two pycolmap calls: the first :data:`RATE_PAIRS` pairs, timed, then the rest in one
    call while the bar moves at the measured rate. Why not batches with a count after each:
    every call costs set-up, and ten calls made matching 1.2x slower (BENCHMARKS.md, "The
    pose step"); a count read from the database while COLMAP writes it is not safe.
    """
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = -1
    pairs = _pairs(names, sequential)
    listing = work / "pairs.txt"
    done, rate = 0, float("inf")  # seconds per pair: unknown until the first call returns
    watch.report("match", 0, len(pairs))
    for batch in (pairs[:RATE_PAIRS], pairs[RATE_PAIRS:]):
        if not batch:
            continue
        watch.check()
        listing.write_text("".join(f"{a} {b}\n" for a, b in batch))
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(listing)
        pairing.block_size = len(batch)
        clock = time.perf_counter()
        with watch.stoppable(), watch.paced("match", done, len(pairs), rate):
            pycolmap.match_image_pairs(
                str(db), matching, pairing, device=pycolmap.Device.cpu,
                cancellation_token=watch.token,
            )  # fmt: skip
        rate = max((time.perf_counter() - clock) / len(batch), 1e-6)
        done += len(batch)
        watch.report("match", done, len(pairs))
    listing.unlink(missing_ok=True)
    watch.check()


def _map(
    db: Path, images: Path, work: Path, names: list[str], seed: int, watch: _Watch
) -> pycolmap.Reconstruction | None:
    """The largest model incremental mapping finds (None: none at all)."""
    sparse = work / "sparse"
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir(parents=True)
    pycolmap.set_random_seed(seed)
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = seed
    options.num_threads = -1
    options.image_names = list(names)
    registered = [0]
    total = len(names)

    def first_pair() -> None:  # a second model (a failed first one) does not move the bar back
        registered[0] = max(registered[0], 2)
        watch.report("map", registered[0], total)
        watch.cancelled()

    def next_image() -> None:
        registered[0] += 1
        watch.report("map", registered[0], total)
        watch.cancelled()

    watch.report("map", 0, total)
    with watch.stoppable():
        models = pycolmap.incremental_mapping(
            str(db), str(images), str(sparse), options,
            initial_image_pair_callback=first_pair, next_image_callback=next_image,
            cancellation_token=watch.token,
        )  # fmt: skip
    watch.check()
    if not models:
        return None
    return max(models.values(), key=lambda r: r.num_reg_images())


def _not_matched(k: int, n: int, missing: list[str]) -> PoseError:
    names = ""
    if missing:
        shown = ", ".join(missing[:SHORT_LIST])
        more = f" and {len(missing) - SHORT_LIST} more" if len(missing) > SHORT_LIST else ""
        names = f" (not registered: {shown}{more})"
    return PoseError(
        f"only {k} of {n} photos could be matched (registered): take more photos with "
        f"overlap, at most about 30 degrees between neighbouring photos{names}"
    )


def _upright(model: pycolmap.Reconstruction) -> None:
    """Move ``model`` into the upright frame (:func:`.frame.upright_similarity`) in place."""
    images = [model.image(i) for i in model.reg_image_ids()]
    rotations = np.stack([im.cam_from_world().rotation.matrix() for im in images])
    centres = np.stack([np.asarray(im.projection_center()) for im in images])
    points = np.array([p.xyz for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3)
    s, R, t = upright_similarity(rotations, centres, points)
    model.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t.reshape(3, 1)))


def _result_from_folder(folder: Path, report: dict) -> PoseResult:
    """The :class:`PoseResult` of a written pose folder (its model and ``poses.json``)."""
    model = read_colmap_model(folder / "sparse" / "0")
    by_name = {im.name: im for im in model.images}
    names = [n for n in report["registered"] if n in by_name]
    return PoseResult(
        folder=folder,
        names=names,
        cameras=[by_name[n].camera for n in names],
        unregistered=list(report["unregistered"]),
        skipped=[tuple(s) for s in report["skipped"]],
        points=model.points.numpy().astype(np.float32).reshape(-1, 3),
        near=float(report["near"]),
        far=float(report["far"]),
        reprojection_error=float(report["reprojection_error"]),
        timings={k: float(v) for k, v in report["timings"].items()},
        distortions=[by_name[n].distortion for n in names],
        sources={p["name"]: p["path"] for p in report.get("photos", [])},
    )


def source_record(source: str | Path) -> list[dict]:
    """What a pose step from ``source`` (a folder of photos or a video) is made from, as
    ``poses.json``'s ``source_files`` records it: each file by resolved path, size and
    modification time."""
    source = Path(source)
    return [_stat(f) for f in ([source] if source.is_file() else list_photos(source))]


def reusable(folder: str | Path, source: str | Path, options: PoseOptions) -> bool:
    """True when the pose folder ``folder`` was made from these very files
    (:func:`source_record`) with these options, so a re-run (``prosplat reconstruct
    PHOTOS``, a second *Import Photos* of one folder) can take it as it is."""
    folder = Path(folder)
    try:
        record = json.loads((folder / POSES_JSON).read_text())
    except (OSError, ValueError):
        return False
    return (
        (folder / "transforms.json").is_file()
        and record.get("options") == asdict(options)
        and record.get("source_files") == source_record(source)
    )


def load_pose_result(folder: str | Path) -> PoseResult:
    """Read a finished pose folder back (``poses.json`` and ``sparse/0``).

    Raises:
        FileNotFoundError: ``folder`` holds no ``poses.json``.
    """
    folder = Path(folder)
    path = folder / POSES_JSON
    if not path.is_file():
        raise FileNotFoundError(f"{folder} is not a pose folder (no {POSES_JSON})")
    return _result_from_folder(folder, json.loads(path.read_text()))


def _write(
    stage: Path, model: pycolmap.Reconstruction, photos: list[Photo]
) -> tuple[list[str], float, float]:
    """sparse/0 and transforms.json into ``stage``; the registered names in input order and
    near/far. The cameras are those read back from sparse/0, what every reader will see."""
    sparse = stage / "sparse" / "0"
    sparse.mkdir(parents=True)
    model.write_text(str(sparse))
    read = read_colmap_model(sparse)
    by_name = {im.name: im for im in read.images}
    names = [p.name for p in photos if p.name in by_name]
    cams = [by_name[n].camera for n in names]
    lenses = [by_name[n].distortion for n in names]
    w2c = np.stack([c.world_to_cam.double().numpy() for c in cams])
    observed = [read.observed[n].numpy() for n in names]
    bounds = near_far(read.points.numpy(), w2c, observed) or FALLBACK_NEAR_FAR
    frames = [
        Frame(c, f"images/{n}", {}, lens) for n, c, lens in zip(names, cams, lenses, strict=True)
    ]
    write_transforms(stage / "transforms.json", frames, {"near": bounds[0], "far": bounds[1]})
    return names, float(bounds[0]), float(bounds[1])


def estimate_poses(
    source: str | Path | Sequence[Path],
    out: str | Path,
    options: PoseOptions | None = None,
    *,
    progress: Callable[[str, int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    overwrite: bool = False,
) -> PoseResult:
    """Poses for photos that have none: a folder of photos, a list of photo files or a video.

    Writes the pose folder ``out`` (``images/`` working copies, ``sparse/0`` COLMAP text model,
    ``transforms.json`` with near/far, ``poses.json`` report, ``database.db``) in the upright
    frame of :mod:`.frame`, whole or not at all.

    Args:
        progress: ``(phase, done, total)`` per step of each phase in :data:`PHASES` (may be
            called from a helper thread; never two calls at once).
        cancel: polled a few times a second; True stops the run (:class:`PoseCancelled`).
        overwrite: replace an existing non-empty ``out`` (its database is reused).
    Raises:
        PoseError: fewer than 2 readable or registered photos, an unreadable video, no photos
            (one line that says what to do).
        PoseCancelled: ``cancel()`` returned True; ``out`` is untouched.
        FileExistsError: ``out`` is a non-empty folder and ``overwrite`` is False.
    """
    require(pycolmap, "pycolmap")
    options = options or PoseOptions()
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise FileExistsError(f"{out} exists and is not empty; pass --overwrite to replace it")
    video = isinstance(source, (str, os.PathLike)) and is_video(source) and Path(source).is_file()
    work = work_folder(out)
    if not work.exists() and overwrite and (out / POSES_JSON).is_file():
        _seed_work(out, work)
    work.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    with _Watch(progress, cancel) as watch:
        clock = time.perf_counter()
        if video:
            watch.report("frames", 0, options.max_frames)
            files = extract_frames(
                Path(source), work / "frames", options.max_frames,
                progress=lambda done, total: watch.report("frames", done, total),
                cancel=watch.cancelled,
            )  # fmt: skip
            timings["frames"] = time.perf_counter() - clock
        else:
            files = _source_files(source)
        clock = time.perf_counter()
        photos, skipped, _ = _prepare(files, work, options, watch)
        timings["prepare"] = time.perf_counter() - clock
        n = len(photos)
        if n < 2:
            why = f"; unreadable: {', '.join(Path(f).name for f, _ in skipped[:SHORT_LIST])}"
            raise PoseError(
                f"only {n} readable photo{'s' if n != 1 else ''} of {len(files)}; structure "
                f"from motion needs at least 2 overlapping photos{why if skipped else ''}"
            )
        db, images = work / DATABASE, work / "images"

        clock = time.perf_counter()
        _extract(db, images, photos, options, watch)
        timings["extract"] = time.perf_counter() - clock

        sequential = options.matching == "sequential" or (
            options.matching == "auto" and (video or n > SEQUENTIAL_ABOVE)
        )
        clock = time.perf_counter()
        _match(db, work, [p.name for p in photos], sequential, watch)
        timings["match"] = time.perf_counter() - clock

        clock = time.perf_counter()
        model = _map(db, images, work, [p.name for p in photos], options.seed, watch)
        timings["map"] = time.perf_counter() - clock
        k = model.num_reg_images() if model is not None else 0
        if k < 2:
            registered = set() if model is None else {im.name for im in model.images.values()}
            raise _not_matched(k, n, [p.name for p in photos if p.name not in registered])

        clock = time.perf_counter()
        watch.report("write", 0, 1)
        error = float(model.compute_mean_reprojection_error())
        _upright(model)
        with staged_folder(out) as stage:
            names, near, far = _write(stage, model, photos)
            registered = set(names)
            manifest = json.loads((work / MANIFEST).read_text())
            by_name = {e["name"]: e for e in manifest["photos"].values()}
            timings["write"] = time.perf_counter() - clock
            one = isinstance(source, (str, os.PathLike))
            report = {
                "source": str(source) if one else [str(f) for f in files],
                "source_files": [_stat(Path(source))] if video else [_stat(f) for f in files],
                "options": asdict(options),
                "features": manifest["features"],
                "matching": "sequential" if sequential else "exhaustive",
                "camera_model": CAMERA_MODEL,
                "registered": names,
                "unregistered": [p.name for p in photos if p.name not in registered],
                "skipped": [list(s) for s in skipped],
                "photos": [by_name[p.name] for p in photos],
                "near": near,
                "far": far,
                "reprojection_error": error,
                "points": int(model.num_points3D()),
                "timings": {k: round(v, 3) for k, v in timings.items()},
                "pycolmap": pycolmap.__version__,
            }
            (stage / POSES_JSON).write_text(json.dumps(report, indent=2) + "\n")
            watch.check()  # the last moment a cancel keeps out untouched
            shutil.move(str(images), str(stage / "images"))
            shutil.move(str(db), str(stage / DATABASE))
        shutil.rmtree(work, ignore_errors=True)
        watch.report("write", 1, 1)
    return _result_from_folder(out, report)
