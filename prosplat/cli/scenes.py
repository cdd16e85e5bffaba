"""``prosplat scenes render|list|pack|sets|subset``: the Blender-rendered synthetic scenes.

``render`` keeps ``--workers`` Blender processes (``python -m scenes.render --jobs-from-stdin``,
the repository's scene scripts) and feeds each the next scene over the line protocol of
:mod:`prosplat.data.render_jobs`; the other subcommands need no Blender.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
from pathlib import Path
from queue import Empty, Queue

from prosplat.cli.options import int_between
from prosplat.data.render_jobs import (
    DEFAULT_SIZE,
    DENOISE_QUALITIES,
    MIN_SIZE,
    add_camera_arguments,
    image_size,
    read_answer,
    size_options,
)
from prosplat.data.scene_sets import SCENE_SETS, link_subset, parse_seeds
from prosplat.data.splits import family_for_seed, split_of


def render_worker_command(args: argparse.Namespace) -> list[str]:
    """The command line of one long-lived Blender worker of ``prosplat scenes render``: Cycles
    gets ``--threads`` threads, by default the machine's cores shared by the workers; ``--roll``
    and ``--lens-range`` travel on it like the image size (every scene of a run shares them).
    Raises ``ValueError`` for an image size :func:`~prosplat.data.render_jobs.image_size`
    refuses."""
    threads = args.threads or max(1, (os.cpu_count() or 1) // args.workers)
    width, height = image_size(args.size, args.width, args.height)
    return (
        [
            sys.executable,
            "-m",
            "scenes.render",
            "--jobs-from-stdin",
            "--out",
            str(args.out),
            *size_options(width, height),
            "--inputs",
            str(args.inputs),
            "--targets",
            str(args.targets),
            "--samples",
            str(args.samples),
            "--threads",
            str(threads),
        ]
        + (["--denoise", "--denoise-quality", args.denoise_quality] if args.denoise else [])
        + camera_options(args.roll, args.lens_range)
    )


def camera_options(roll: float, lens_range: tuple[float, float] | None) -> list[str]:
    """The worker's ``--roll`` / ``--lens-range`` options, only where they are not the
    defaults: a run without them starts the very workers it started before they existed.
    ``repr`` writes the floats exactly, so the worker draws what the parent asked for."""
    out = ["--roll", repr(roll)] if roll else []
    if lens_range is not None:
        out += ["--lens-range", f"{lens_range[0]!r}-{lens_range[1]!r}"]
    return out


def cmd_scenes_render(args: argparse.Namespace) -> int:
    """Render scenes ``seed .. seed+count-1`` with ``--workers`` long-lived Blender processes
    (``scenes.render --jobs-from-stdin``), each fed the next missing scene as it finishes one."""
    from tqdm import tqdm

    if args.count < 1 or args.workers < 1 or args.samples < 1:
        print("prosplat scenes render: --count, --workers, --samples must be >= 1", file=sys.stderr)
        return 2
    try:
        image_size(args.size, args.width, args.height)
    except ValueError as e:
        print(f"prosplat scenes render: {e}", file=sys.stderr)
        return 2
    if args.threads is not None and args.threads < 1:
        print("prosplat scenes render: --threads must be >= 1", file=sys.stderr)
        return 2
    if args.denoise_quality != "high" and not args.denoise:
        print("prosplat scenes render: --denoise-quality needs --denoise", file=sys.stderr)
        return 2
    for s in (args.seed, args.seed + args.count - 1):
        split_of(s)  # raises with the valid range for seeds outside every split
    jobs = []
    for seed in range(args.seed, args.seed + args.count):
        name = args.scene or family_for_seed(seed)
        if (args.out / f"{name}_{seed:06d}").is_dir():
            continue  # complete: folders only appear when finished
        jobs.append((name, seed))
    skipped = args.count - len(jobs)
    if skipped:
        print(f"{skipped} of {args.count} scenes already rendered in {args.out}; skipping them")
    if not jobs:
        return 0
    cmd = render_worker_command(args)
    queue: Queue = Queue()
    for job in jobs:
        queue.put(job)
    failures: list[tuple[str, int, list[str]]] = []
    bar = tqdm(total=len(jobs), desc="rendering scenes", unit="scene")
    lock = threading.Lock()
    stop = threading.Event()  # Ctrl-C: no worker takes another scene

    def worker() -> None:
        """One long-lived Blender process fed scene after scene (start-up paid once); a
        process that dies fails its current scene and is replaced for the next."""
        proc = None
        while not stop.is_set():
            try:
                name, seed = queue.get_nowait()
            except Empty:
                break
            if proc is None:
                proc = subprocess.Popen(
                    cmd,
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    text=True,
                )
            proc.stdin.write(f"{name} {seed}\n")
            proc.stdin.flush()
            answer, tail = read_answer(proc.stdout)
            if answer is None:  # the process died mid-scene: a fresh one takes the next
                answer = {"error": tail + [f"(the Blender worker exited with {proc.wait()})"]}
                proc = None
            with lock:
                if "folder" not in answer:
                    failures.append((name, seed, answer.get("error", [])))
                bar.update()
        if proc is not None:
            proc.stdin.close()
            proc.wait()

    feeders = [
        threading.Thread(target=worker, daemon=True) for _ in range(min(args.workers, len(jobs)))
    ]
    for t in feeders:
        t.start()
    try:
        for t in feeders:
            t.join()
    except KeyboardInterrupt:
        # the terminal's SIGINT reaches the Blender workers too: each removes its half-made
        # scene folder and exits; a worker stopped otherwise ends when its stdin closes
        stop.set()
        raise
    bar.close()
    for name, seed, tail in failures:
        print(f"scene {name} seed {seed} failed:\n  " + "\n  ".join(tail), file=sys.stderr)
    print(
        f"rendered {len(jobs) - len(failures)} scenes into {args.out.resolve()}"
        + (f"; {len(failures)} failed (re-run the same command to retry them)" if failures else "")
    )
    return 1 if failures else 0


def cmd_scenes_list(args: argparse.Namespace) -> int:
    """One line per scene folder: split, family, tags, views and input overlap (for binning)."""
    from prosplat.data.dataset import find_scenes

    folders = find_scenes(args.out)
    if not folders:
        print(f"no scene folders in {args.out}", file=sys.stderr)
        return 1
    print(
        "| scene | split | family | tags | inputs | targets (interp/extrap) | mean input overlap | near | far |"
    )
    print("|---|---|---|---|---:|---|---:|---:|---:|")
    for folder in folders:
        meta = json.loads((folder / "transforms.json").read_text())
        frames = meta["frames"]
        n_in = sum(f.get("split") == "input" for f in frames)
        kinds = [f.get("target_kind") for f in frames if f.get("split") == "target"]
        print(
            f"| {folder.name} | {meta.get('split_set', '?')} | {meta.get('family', '?')} | "
            f"{','.join(meta.get('tags', [])) or '-'} | {n_in} | {len(kinds)} "
            f"({kinds.count('interpolation')}/{kinds.count('extrapolation')}) | "
            f"{meta.get('mean_input_overlap', float('nan')):.2f} | {meta['near']:.3g} | {meta['far']:.3g} |"
        )
    return 0


def cmd_scenes_pack(args: argparse.Namespace) -> int:
    """Pack scene folders into size-bounded .npz files (:mod:`prosplat.data.packed`)."""
    from tqdm import tqdm

    from prosplat.data.dataset import find_scenes
    from prosplat.data.packed import pack_scenes

    folders = find_scenes(args.data)[args.first :]
    if args.count is not None:
        folders = folders[: args.count]
    if not folders:
        print(f"prosplat scenes pack: no scene folders under {args.data}", file=sys.stderr)
        return 2
    # estimate the scenes per pack from the first one, then fill each pack up to the bound
    depth = not args.no_depth
    probe_path = args.out.with_name(f".{args.out.name}.probe.npz")
    opts = dict(depth=depth, jpeg_quality=args.jpeg_quality, depth_bits=args.depth_bits)
    probe = pack_scenes(folders[:1], probe_path, True, **opts)
    per_scene = probe.stat().st_size
    probe.unlink()
    per_pack = max(1, int(args.max_mb * 2**20 * 0.9 // per_scene))
    chunks = [folders[i : i + per_pack] for i in range(0, len(folders), per_pack)]
    for i, chunk in enumerate(tqdm(chunks, desc="packing", unit="pack")):
        path = args.out.with_name(f"{args.out.name}_{i:03d}.npz")
        pack_scenes(chunk, path, **opts)
        print(f"{path}: {len(chunk)} scenes, {path.stat().st_size / 2**20:.1f} MB")
    return 0


def cmd_scenes_sets(args: argparse.Namespace) -> int:
    """Print the named scene sets, or the commands that render one (``--seeds``: part of it)."""
    if args.name is None:
        for s in SCENE_SETS.values():
            print(f"{s.name:10s} seeds {s.seeds}: {s.about}")
        return 0
    if args.name not in SCENE_SETS:
        print(
            f"prosplat scenes sets: no set {args.name!r}; one of {', '.join(SCENE_SETS)}",
            file=sys.stderr,
        )
        return 2
    try:
        commands = SCENE_SETS[args.name].render_commands(args.seeds, args.root)
    except ValueError as e:
        print(f"prosplat scenes sets: {e}", file=sys.stderr)
        return 2
    print("\n".join(commands))
    return 0


def cmd_scenes_subset(args: argparse.Namespace) -> int:
    """Link the scenes of ``--data`` with the given seeds into ``--out``."""
    try:
        seeds = parse_seeds(args.seeds)
        dest = link_subset(args.data, seeds, args.out)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"prosplat scenes subset: {e}", file=sys.stderr)
        return 2
    print(f"{dest}: links to {len(seeds)} scenes of {args.data}")
    return 0


def add_parser(sub) -> None:
    """``prosplat scenes ...`` into the top-level subparsers ``sub``."""
    scenes = sub.add_parser("scenes", help="Blender-rendered synthetic scenes (needs bpy)")
    scenes_sub = scenes.add_subparsers(dest="scenes_command", required=True)
    rend = scenes_sub.add_parser(
        "render",
        help="render seeded scenes with Cycles into scene folders",
        description="Render scenes seed..seed+count-1 with Cycles on the CPU, each into "
        "OUT/NAME_SEED/ (transforms.json, images/, depth/). Finished scenes are "
        "skipped, so an interrupted run can simply be re-run. Seeds decide the "
        "split: train 0-899999, val 900000-949999, test 950000-999999.",
    )
    rend.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    rend.add_argument("--count", type=int, default=1, help="number of scenes (default 1)")
    rend.add_argument("--out", type=Path, required=True, help="dataset folder")
    rend.add_argument(
        "--size",
        type=int,
        default=None,
        metavar="N",
        help=f"square images, N x N px (default {DEFAULT_SIZE} x {DEFAULT_SIZE} when neither "
        "--size nor --width/--height is given)",
    )
    rend.add_argument(
        "--width",
        type=int,
        default=None,
        metavar="W",
        help=f"image width in px, with --height (instead of --size), e.g. --width 128 --height "
        f"72 for 16:9; each side >= {MIN_SIZE}. The lens spans the longer side (Blender's "
        "36 mm sensor, fit AUTO), so fx = fy = lens_mm / 36 * max(W, H)",
    )
    rend.add_argument(
        "--height", type=int, default=None, metavar="H", help="image height in px, with --width"
    )
    rend.add_argument(
        "--inputs", type=int, default=4, help="input views per scene, 2-6 (default 4)"
    )
    rend.add_argument("--targets", type=int, default=8, help="target views per scene (default 8)")
    rend.add_argument(
        "--samples", type=int, default=32, help="Cycles samples per pixel (default 32)"
    )
    rend.add_argument("--denoise", action="store_true", help="run Cycles' denoiser (default off)")
    rend.add_argument(
        "--denoise-quality",
        choices=DENOISE_QUALITIES,
        default="high",
        help="the denoiser's settings (with --denoise): high (Blender's default) or fast "
        "(no prefiltered albedo/normal passes, OIDN's balanced network: 0.7-0.8x the colour "
        "render's time, 0.1-0.9 dB from high; for training data)",
    )
    rend.add_argument(
        "--workers", type=int, default=2, help="parallel Blender processes (default 2)"
    )
    rend.add_argument(
        "--threads",
        type=int,
        default=None,
        help="Cycles threads per worker (default: the machine's cores / --workers); fewer "
        "leaves cores to a training run beside the rendering",
    )
    rend.add_argument(
        "--scene",
        default=None,
        help="family (room, tabletop, open), hard scene (textureless, "
        "thin_structures, repeated_pattern, specular, near_far, "
        "inside_outside) or capture scene (object_ring: objects on a plain background "
        "ringed by cameras, like DTU); default: the seed's family",
    )
    add_camera_arguments(rend)
    rend.set_defaults(func=cmd_scenes_render)
    lst = scenes_sub.add_parser(
        "list",
        help="list rendered scenes with their split, family and input overlap",
        description="Print a Markdown table of the scene folders under --out: split, family, "
        "hard-scene tags, view counts and the mean overlap between input views "
        "(to bin benchmarks by baseline).",
    )
    lst.add_argument("--out", type=Path, required=True, help="dataset folder")
    lst.set_defaults(func=cmd_scenes_list)
    pk = scenes_sub.add_parser(
        "pack",
        help="pack rendered scene folders into .npz files to move training data",
        description="Pack the scene folders under --data into OUT_000.npz, OUT_001.npz, ... "
        "of at most --max-mb each (JPEG images, q95 by default; float16 depth; float64 cameras): "
        "training reads packs like folders, with only numpy, Pillow and torch. "
        "Existing pack files are never replaced.",
    )
    pk.add_argument("--data", type=Path, required=True, help="dataset folder of scene folders")
    pk.add_argument("--out", type=Path, required=True, help="pack path prefix, e.g. packs/train")
    pk.add_argument("--max-mb", type=float, default=48.0, help="size bound per pack (default 48)")
    pk.add_argument("--first", type=int, default=0, help="skip the first N scenes (sorted)")
    pk.add_argument("--count", type=int, default=None, help="pack at most N scenes")
    pk.add_argument(
        "--no-depth",
        action="store_true",
        help="leave the depth maps out (about 40 %% smaller; enough for `prosplat train curate`, "
        "not for training the generator with depth terms)",
    )
    pk.add_argument(
        "--jpeg-quality",
        type=int_between(1, 95),
        default=95,
        metavar="Q",
        help="JPEG quality of the images, 1-95 (default 95); lower fits more scenes into a "
        "bounded transfer",
    )
    pk.add_argument(
        "--depth-bits",
        type=int_between(1, 10),
        default=10,
        metavar="BITS",
        help="mantissa bits kept of the float16 depth, 1-10 (default 10: all); fewer pack "
        "smaller (7: 0.4 %% relative error)",
    )
    pk.set_defaults(func=cmd_scenes_pack)

    st = scenes_sub.add_parser(
        "sets",
        help="the named scene sets the shipped weights and the ladder use, and their commands",
        description="Without NAME, list the named sets (prosplat.data.scene_sets); with it, "
        "print the `prosplat scenes render` commands that render it (or --seeds of it) into "
        "ROOT/NAME. The commands skip finished scenes, so a partial set is completed.",
    )
    st.add_argument("name", nargs="?", default=None, help="a set, e.g. train128 or test128")
    st.add_argument(
        "--seeds",
        default=None,
        help="seed ranges, e.g. '10000-10359 hard:0-4' (hard:A-B: the hard scenes of render "
        "rounds A-B); default: the whole set",
    )
    st.add_argument("--root", default="data", help="folder of the sets (default data)")
    st.set_defaults(func=cmd_scenes_sets)
    sb = scenes_sub.add_parser(
        "subset",
        help="link the scenes of given seeds into a folder, to train on exactly those",
        description="Make --out a folder of relative links to the scene folders of --data "
        "whose seeds are in --seeds, made aside and moved into place; a folder that holds "
        "exactly those links already is left alone, one of other links is replaced. Every "
        "seed must be rendered.",
    )
    sb.add_argument("--data", type=Path, required=True, help="a scene set, e.g. data/train128")
    sb.add_argument(
        "--seeds", required=True, help="seed ranges, e.g. '10000-10135 hard:0-1' (see `sets`)"
    )
    sb.add_argument("--out", type=Path, required=True, help="the folder of links to make")
    sb.set_defaults(func=cmd_scenes_subset)
