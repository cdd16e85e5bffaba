"""The worker's tasks: each takes JSON-ready ``params`` and a :class:`~prosplat.worker.Progress`
and returns a result dict (numpy arrays under ``"arrays"``).

Frames (input views) are ``{"image": path, "camera": camera dict}`` and target views
``{"name": str, "camera": camera dict}``; camera dicts are described in
:mod:`prosplat.convert.posed`. Gaussians come as ``"arrays"`` (the point attributes of
:mod:`prosplat.convert.pointcloud`, as the Blender mesh holds them) plus an optional
``"matrix_world"``, or as a ``"ply"`` path. The ``poses`` task (camera poses for photos with
none) is :mod:`prosplat.worker.pose_task`.
"""

from __future__ import annotations

import re
import statistics
import time
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from prosplat.convert.pointcloud import from_attributes, to_attributes, transform_gaussians
from prosplat.convert.posed import camera_from_dict, camera_to_blender_dict, read_posed_images
from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.worker.models import MODELS
from prosplat.worker.pose_task import task_poses
from prosplat.worker.protocol import Cancelled, Progress

SIZE_MULTIPLE = 32  # the generator's image sizes are multiples of this (DepthSplat's: 16 or 32)


def pick_device(name: str | None) -> torch.device:
    """``auto`` (CUDA, then MPS, then CPU), ``cpu``, ``cuda`` or ``mps``; an unavailable
    device is an error rather than a silent fallback, so the preference means what it says."""
    name = (name or "auto").lower()
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        mps = getattr(torch.backends, "mps", None)
        return torch.device("mps" if mps is not None and mps.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' was asked for but torch sees no CUDA GPU; pick auto or cpu")
    if name == "mps":
        mps = getattr(torch.backends, "mps", None)
        if mps is None or not mps.is_available():
            raise ValueError("device 'mps' was asked for but is not available; pick auto or cpu")
    if name not in ("cpu", "cuda", "mps"):
        raise ValueError(f"unknown device {name!r}; use auto, cpu, cuda or mps")
    return torch.device(name)


def load_model(weights: str | None, device: torch.device, improve: str | bool | None = False):
    """The model for a job, from this process's :data:`~prosplat.worker.models.MODELS` cache
    (loaded on first use, then kept for the next jobs; see :mod:`prosplat.worker.models`).

    ``improve``: the stage-2 checkpoint path, None for the shipped one (if any), False for
    none (reconstruction never needs stage 2, so it does not pay for loading it).
    """
    return MODELS.get(weights, device, improve)


def load_frames(frames: list, progress: Progress, lo: float, hi: float, background=None):
    """Images [N,3,H,W] and cameras of input frames, all at the first frame's size; RGBA
    images composited over ``background`` ([3] in 0-1; None: over black)."""
    from prosplat.core.image_io import composite, read_image_rgba

    if not isinstance(frames, list) or not frames:
        raise ValueError("no input views given; an input view needs an image and a camera")
    images, cameras = [], []
    for i, fr in enumerate(frames):
        progress(lo + (hi - lo) * i / len(frames), f"reading input image {i + 1}/{len(frames)}")
        name = fr.get("name", f"input {i}") if isinstance(fr, dict) else f"input {i}"
        if not isinstance(fr, dict) or not fr.get("image"):
            raise ValueError(f"input view '{name}' has no image; give every input camera an image")
        cam = camera_from_dict(fr.get("camera"), f"input view '{name}'")
        rgb, alpha = read_image_rgba(fr["image"])
        img = composite(rgb, alpha, torch.tensor(background or (0.0, 0.0, 0.0)))
        if (img.shape[2], img.shape[1]) != (cam.width, cam.height):
            cam = cam.resized(img.shape[2], img.shape[1])  # the file is the truth for the size
        images.append(img)
        cameras.append(cam)
    w, h = cameras[0].width, cameras[0].height
    for i in range(1, len(images)):
        if (cameras[i].width, cameras[i].height) != (w, h):
            images[i] = _resize(images[i], w, h)
            cameras[i] = cameras[i].resized(w, h)
    return torch.stack(images), cameras


def _resize(img: torch.Tensor, w: int, h: int) -> torch.Tensor:
    out = F.interpolate(
        img[None], size=(h, w), mode="bilinear", antialias=True, align_corners=False
    )
    return out[0].clamp(0, 1)


def generator_size(w: int, h: int, max_size: int | None) -> tuple[int, int]:
    """Multiples of 32 near (w, h), scaled down so the long side is at most ``max_size``."""
    s = 1.0 if not max_size else min(1.0, max_size / max(w, h))
    snap = lambda x: max(SIZE_MULTIPLE, int(round(x * s / SIZE_MULTIPLE)) * SIZE_MULTIPLE)  # noqa: E731
    return snap(w), snap(h)


def _gaussians_from(params: dict) -> Gaussians:
    from prosplat.core.ply import read_ply

    if params.get("arrays") is not None:
        g = from_attributes(params["arrays"])
    elif params.get("ply"):
        g = read_ply(params["ply"], dtype=torch.float64)
    else:
        raise ValueError("no Gaussians given: pass 'arrays' (point attributes) or 'ply' (a path)")
    if params.get("matrix_world") is not None:
        g = transform_gaussians(g, params["matrix_world"])
    return g


# ---- tasks ----------------------------------------------------------------------------------
def task_read_posed_images(params: dict, progress: Progress) -> dict:
    progress(0.1, "reading cameras")
    posed, meta = read_posed_images(params["path"], params.get("images_dir"))
    if not posed:
        raise ValueError(f"{params['path']} holds no cameras")
    # a frame listed twice is one view: keep the first frame of each image file
    kept, seen = [], set()
    for p in posed:
        if p.image is None or p.image not in seen:
            kept.append(p)
        seen.add(p.image)
    if len(kept) < len(posed):
        progress.warn(
            f"left out {len(posed) - len(kept)} frames of {params['path']} that list an image "
            "an earlier frame lists"
        )
        posed = kept
    frames = [
        {
            "name": p.name,
            "image": str(p.image) if p.image else None,
            "blender": camera_to_blender_dict(p.camera),
            "split": p.split,
            "target_kind": p.target_kind,
        }  # fmt: skip
        for p in posed
    ]
    bounds = {k: float(meta[k]) for k in ("near", "far") if isinstance(meta.get(k), (int, float))}
    return {"frames": frames, **bounds}


def task_write_transforms(params: dict, progress: Progress) -> dict:
    from prosplat.convert.nerfstudio import Frame, write_transforms

    progress(0.5, "writing transforms.json")
    frames = [
        Frame(camera_from_dict(f["camera"], f["file_path"]), f["file_path"], f.get("extra", {}))
        for f in params["frames"]
    ]
    path = write_transforms(params["path"], frames, params.get("meta"), overwrite=False)
    return {"path": str(path)}


def task_import_ply(params: dict, progress: Progress) -> dict:
    from prosplat.core.ply import read_ply

    progress(0.1, "reading PLY")
    g = read_ply(params["path"], dtype=torch.float64, on_warning=progress.warn)
    progress(0.6, "converting")
    return {"count": len(g), "sh_degree": g.sh_degree, "arrays": to_attributes(g)}


def task_export_ply(params: dict, progress: Progress) -> dict:
    from prosplat.core.ply import write_ply

    progress(0.1, "converting")
    g = _gaussians_from(params)
    progress(0.4, "writing PLY")
    write_ply(g, params["path"], overwrite=bool(params.get("overwrite", False)))
    return {"path": str(params["path"]), "count": len(g)}


def task_reconstruct(params: dict, progress: Progress) -> dict:
    """Generator on the input views -> pruned Gaussians (point attributes, optional PLY)."""

    t0 = time.perf_counter()
    refine_budget = _refine_budget(params)  # a bad budget is refused before any work
    device = pick_device(params.get("device"))
    progress(0.02, "loading the generator")
    model = load_model(params.get("weights"), device)
    from prosplat.geometry.view_choice import choose_frames

    max_views = getattr(getattr(model.generator, "config", None), "max_views", 6)
    frames, views = choose_frames(params.get("frames"), max_views, params.get("view_choice"))
    images, cameras = load_frames(frames, progress, 0.1, 0.3, params.get("background"))
    if len(cameras) < 2:
        raise ValueError(f"reconstruction needs at least 2 input views, got {len(cameras)}")
    w, h = generator_size(cameras[0].width, cameras[0].height, params.get("max_size"))
    if (w, h) != (cameras[0].width, cameras[0].height):
        images = torch.stack([_resize(im, w, h) for im in images])
        cameras = [c.resized(w, h) for c in cameras]
    # the generator runs at the size its weights were trained at (its Gaussians render at any
    # size); refinement and the references use the inputs at the Input Size
    sweep = ", its depth sweep" if getattr(model, "depth_sweep", None) is not None else ""
    progress(
        0.35, f"running the generator on {len(cameras)} views{sweep}, then the Gaussian budget"
    )
    refining = any(b is not None for b in refine_budget)
    from prosplat.geometry.merge import MergeOptions

    # per job: the model is cached across jobs, so the switch is set (or cleared) every time
    model.merge_flat = MergeOptions() if params.get("merge_flat") else None
    near, far, range_source, anchors = params.get("near"), params.get("far"), "given", None
    if near is None or far is None:  # the depth range from the inputs' own points, else cameras
        from prosplat.pipeline.depth_range import can_triangulate, depth_range

        triangulate = bool(params.get("triangulate", True))
        if triangulate and can_triangulate():
            progress(0.33, "triangulating the inputs (SIFT) for the scene's depth range")
        r = depth_range(images, cameras, near=near, far=far, triangulate=triangulate)
        near, far, range_source = r.near, r.far, r.source
        anchors = r.anchors if params.get("anchors", False) else None  # opt-in, as in the CLI
    rec = model.reconstruct(
        images.to(device), cameras, near, far, budget=params.get("budget") or None,
        anchors=anchors,
    )  # fmt: skip
    gw, gh = rec.cameras[0].width, rec.cameras[0].height
    g, stats, t_gen = rec.gaussians.to("cpu"), rec.prune_stats, rec.timings["generator"]
    if len(g) == 0:
        raise ValueError("the generator produced no visible Gaussians for these views")
    trust = None
    if params.get("trust_check", True) and len(cameras) >= 3:
        from prosplat.pipeline.trust import leave_one_out

        def step(k: int, count: int) -> None:  # Esc stops between left-out inputs
            progress(0.5 + 0.25 * k / count,
                     f"leave-one-out {k + 1}/{count}: can the views beat the nearest photo?")  # fmt: skip

        trust = leave_one_out(model, images.to(device), cameras, near, far, progress=step,
                              anchors=anchors)  # fmt: skip
    t_refine = 0.0
    if refining:
        depths = rec.depths_for(images)
        depths = None if depths is None else depths.cpu()
        g, t_refine = _refine(refine_budget, g, images, cameras, depths, progress)
    if params.get("ply"):
        from prosplat.core.ply import write_ply

        progress(0.9, "writing PLY")
        write_ply(g, params["ply"])
    stats = {k: int(v) for k, v in stats.items()}
    return {
        "count": len(g), "sh_degree": g.sh_degree, "stats": stats, "size": [w, h],
        "generator_size": [gw, gh], "near_far": [near, far], "near_far_source": range_source,
        "anchored_views": sum(f.used for f in rec.anchor_fits),
        "seconds": {"generator": t_gen, "refine": t_refine, "total": time.perf_counter() - t0},
        "arrays": to_attributes(g), "views": [f.get("name") for f in frames], "view_reason": views,
        "generator": generator_info(model.generator),
        "trust": None if trust is None else trust.as_dict(),
        "trust_warning": None if trust is None else trust.message(),
    }  # fmt: skip


def generator_info(generator) -> dict[str, str]:
    """What made the Gaussians, for the add-on's report: ``{"kind": "prosplat"}``, or for a
    DepthSplat checkpoint its kind, ViT, variant (the released name, when known) and licence
    (base and large are non-commercial)."""
    if getattr(generator, "kind", None) != "depthsplat":
        return {"kind": "prosplat"}
    return {"kind": "depthsplat", "vit": generator.config.monodepth_vit_type,
            "variant": str(getattr(generator.encoder, "variant", "")), "licence": generator.licence}  # fmt: skip


def _refine_budget(params: dict) -> tuple[int | None, float | None]:
    """(steps, seconds) of the task's refinement, (None, None) when off (0 or missing), not
    both; checked when the task starts, so a bad budget costs nothing."""
    from prosplat.pipeline.refine import check_budget

    steps, seconds = params.get("refine_steps") or None, params.get("refine_seconds") or None
    if steps is not None or seconds is not None:
        check_budget(steps, seconds)
    return steps, seconds


def _refine(budget: tuple, g: Gaussians, images, cameras, depths, progress: Progress):
    """Refine the pruned Gaussians against the inputs for ``budget`` (steps, seconds) from
    :func:`_refine_budget`, reporting each step between 0.8 and 0.9; a cancel raises
    :class:`~prosplat.worker.Cancelled` like every other step. Returns (Gaussians, seconds)."""
    from prosplat.pipeline.refine import refine

    steps, seconds = budget
    start = time.perf_counter()

    def report(step: int, total, loss: float) -> None:
        done = step / total if total else min((time.perf_counter() - start) / seconds, 1.0)
        what = f"step {step}/{total}" if total else f"step {step}, {seconds:g} s budget"
        progress(0.8 + 0.1 * done, f"refining against the inputs: {what}, loss {loss:.4f}")

    progress(0.8, "refining against the inputs")
    result = refine(
        g, images.to(g.means.device, g.means.dtype), cameras, steps=steps, seconds=seconds,
        depths=depths, progress=report, cancel=progress.cancelled,
    )  # fmt: skip
    if result.stats.cancelled:
        raise Cancelled("cancelled while refining")
    return result.gaussians, result.stats.seconds


def _distill(params: dict, model, g: Gaussians, images, in_cams, cams, progress: Progress):
    """``distill_steps``: enhance every target with the inputs' aspect ratio (progress 0.2 to
    0.5), fit the Gaussians to the inputs and those views (0.5 to 0.8), so that every target
    then renders raw from one consistent set of Gaussians (:mod:`prosplat.pipeline.distill`: no
    flicker along a camera path). Returns (Gaussians, whether they were distilled); with no
    target of the inputs' aspect ratio it warns and keeps ``g``."""
    from prosplat.pipeline.distill import distill, enhance_views, fits_inputs

    h, w = images.shape[-2:]
    same = [c for c in cams if fits_inputs(c, h, w)]
    if not same:
        progress.warn("no target camera has the input images' aspect ratio; not distilled")
        return g, False
    if len(same) < len(cams):
        progress.warn(
            f"{len(cams) - len(same)} target camera(s) of another aspect ratio than the input "
            "images are rendered from the distilled Gaussians without being fitted"
        )
    images = images.to(g.means.dtype)
    views = enhance_views(
        g, images, in_cams, same, model.improver,
        progress=lambda i, n: progress(0.2 + 0.3 * i / n, f"enhancing views to distil ({i + 1}/{n})"),
    )  # fmt: skip
    steps = int(params["distill_steps"])

    def report(step: int, total, loss: float) -> None:
        progress(0.5 + 0.3 * step / total, f"distilling: step {step}/{total}, loss {loss:.4f}")

    # over black, as _render_one renders the views
    result = distill(
        g, images, in_cams, views, same, steps=steps,
        progress=report, cancel=progress.cancelled,
    )  # fmt: skip
    if result.stats.cancelled:
        raise Cancelled("cancelled while distilling")
    return result.gaussians, True


def _unique_stem(folder: Path, stem: str, suffixes: list[str]) -> str:
    """``stem``, or ``stem-2``, ``stem-3``... so that no file ``stem+suffix`` exists."""
    candidate, k = stem, 1
    while any((folder / f"{candidate}{s}").exists() for s in suffixes):
        k += 1
        candidate = f"{stem}-{k}"
    return candidate


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "view"


#: The render task's ``fill_holes`` values: where the holes no input saw show a continuation
#: of the render's own colours instead of black. "raw" (the default) fills raw views only (no
#: enhancement, a guarded view, distilled views): generator v16 leaves what no input saw
#: empty, and its raw views on black lose 8.7-9.8 dB (BENCHMARKS "Raw views filled by
#: default"); "all" also blends enhanced views with the fill (level in PSNR, worse in
#: LPIPS); "off": black.
FILL_MODES = ("off", "raw", "all")


def fill_mode(value) -> str:
    """``params["fill_holes"]`` as one of :data:`FILL_MODES`: None is "raw", True "all" and
    False "off" (the values before the modes)."""
    if value is None:
        return "raw"
    if isinstance(value, bool):
        return "all" if value else "off"
    mode = str(value).lower()
    if mode not in FILL_MODES:
        raise ValueError(
            f"fill_holes must be one of {', '.join(FILL_MODES)} (or true / false), got {value!r}"
        )
    return mode


def _render_one(model, g: Gaussians, cam: Camera, images, cameras, enhance: bool, fill="off"):
    """``model.render``: rasterize, then (``enhance``) the improvement model with MORI;
    ``fill`` (:data:`FILL_MODES`): which views show the holes no input saw as a continuation
    of the render's colours."""
    return model.render(
        g, cam, images, cameras if cameras else None, enhance=enhance,
        fill_holes=fill != "off", fill_enhanced=fill == "all",
    )  # fmt: skip


def _sequence_of(targets: list) -> tuple[str, list[int]] | None:
    """(name, frame numbers) when the targets are one camera over a frame range (each has
    ``"sequence"`` and ``"frame"``, as the add-on's Frame Range mode sends), else None."""
    names = {t.get("sequence") for t in targets}
    if len(names) != 1 or None in names or any(t.get("frame") is None for t in targets):
        return None
    return str(names.pop()), [int(t["frame"]) for t in targets]


def _sequence_prefix(folder: Path, name: str, frames: list[int], suffixes: list[str]) -> str:
    """``name``, or ``name-2``, ``name-3``... so that no frame file of the sequence exists:
    a rerun never replaces a frame, and never mixes numbered names into the old sequence."""
    candidate, k = name, 1
    while any((folder / f"{candidate}_{f:04d}{s}").exists() for f in frames for s in suffixes):
        k += 1
        candidate = f"{name}-{k}"
    return candidate


def task_render(params: dict, progress: Progress) -> dict:
    """Render target cameras (and enhance them) into files in ``output_dir``.

    A camera path (targets with ``"sequence"`` and ``"frame"``) becomes an image sequence
    ``NAME_0001.png, NAME_0002.png, ...`` numbered by frame, under one prefix chosen so that
    no frame file exists yet. Progress is reported per view; a cancel or an error stops at
    the next view and removes the files this job wrote, so a job leaves all or nothing.
    ``fill_holes``: which views show the holes no input saw filled (:data:`FILL_MODES`,
    default "raw").
    """

    out_dir = Path(params["output_dir"])
    targets = params.get("targets") or []
    if not targets:
        raise ValueError("no cameras to render; select a camera or set an active one")
    params = {**params, "fill_holes": fill_mode(params.get("fill_holes"))}  # fails before work
    for note in params.get("notes") or []:  # what the caller found (e.g. the add-on's inputs)
        progress.warn(str(note))
    frames = params.get("inputs") or []
    for fr in frames:
        if fr.get("image") and Path(fr["image"]).resolve().parent == out_dir.resolve():
            raise ValueError(
                f"the output folder {out_dir} holds the input images; choose another folder so "
                "renders can never replace them"
            )
    cams = [camera_from_dict(t.get("camera"), f"target '{t.get('name')}'") for t in targets]
    device = pick_device(params.get("device"))
    progress(0.02, "loading the model")
    enhance = bool(params.get("enhance", True))
    improve = (params.get("improve_weights") or None) if enhance else False
    model = load_model(params.get("weights"), device, improve)
    if enhance and getattr(model, "improver", None) is None:
        progress.warn("no enhancement weights are available; saved raw renders instead")
        enhance = False
    images, in_cams = (None, [])
    if frames:
        images, in_cams = load_frames(frames, progress, 0.05, 0.15, params.get("background"))
        images = images.to(device)
    elif enhance:
        progress.warn("no input views to borrow texture from; saved raw renders instead")
        enhance = False
    g = _gaussians_from(params).to(device, torch.float32)
    start = 0.2  # where the per-view progress begins
    distilled = False
    if params.get("distill_steps") and enhance:
        g, distilled = _distill(params, model, g, images, in_cams, cams, progress)
        enhance, start = not distilled, 0.8 if distilled else start
    out_dir.mkdir(parents=True, exist_ok=True)
    sequence = _sequence_of(targets)
    suffixes = _suffixes(params, enhance)
    prefix = None
    if sequence is not None:
        prefix = _sequence_prefix(out_dir, _safe_name(sequence[0]), sequence[1], suffixes)
    views: list[dict] = []
    written: list[Path] = []
    try:
        for i, (t, cam) in enumerate(zip(targets, cams)):
            what = f"frame {t['frame']}" if prefix else str(t.get("name", i))
            progress(start + (1 - start) * i / len(cams), f"rendering {what} ({i + 1}/{len(cams)})")
            t_view = time.perf_counter()
            views.append(_render_and_save(model, g, cam, images, in_cams, enhance, params,
                                          progress, out_dir, t, i, prefix, written, frames))  # fmt: skip
            views[-1]["seconds"] = time.perf_counter() - t_view  # render, enhance and write
            enhance = views[-1]["enhanced"]
            views[-1]["distilled"] = distilled
    except BaseException:
        for path in written:  # all or nothing: a cancelled sequence leaves no frames behind
            path.unlink(missing_ok=True)
        raise
    result: dict[str, Any] = {"views": views, "output_dir": str(out_dir)}
    result["seconds_per_view"] = statistics.median(v["seconds"] for v in views)
    if prefix is not None:
        result["sequence"] = {"prefix": prefix, "frames": sequence[1],
                              "pattern": f"{prefix}_####.png", "first": views[0]["image"]}  # fmt: skip
    return result


def _suffixes(params: dict, enhance: bool) -> list[str]:
    """The files one view writes: the image, the raw render when asked for and enhanced,
    the depth when asked for."""
    suffixes = [".png"] + ["_raw.png"] * bool(params.get("save_raw") and enhance)
    return suffixes + ["_depth.exr"] * bool(params.get("save_depth"))


def _render_and_save(model, g, cam, images, in_cams, enhance, params, progress, out_dir,
                     t, i, prefix, written, frames) -> dict:  # fmt: skip
    """One view: render (raw if enhancement fails), write its files, say what was written."""
    from prosplat.core.image_io import write_depth, write_image

    fill = params["fill_holes"]  # one of FILL_MODES: task_render parsed it
    try:
        v = _render_one(model, g, cam, images, in_cams, enhance, fill)
    except ValueError as e:
        if not enhance or "improv" not in str(e).lower():
            raise
        progress.warn(f"enhancement unavailable ({e}); saved raw renders instead")
        enhance = False
        v = _render_one(model, g, cam, images, in_cams, False, fill)
    suffixes = _suffixes(params, enhance)  # enhancement may have just fallen back to raw
    if prefix is not None:
        stem = f"{prefix}_{int(t['frame']):04d}"
    else:
        stem = _unique_stem(out_dir, _safe_name(str(t.get("name", f"view_{i:03d}"))), suffixes)
    rec = {"name": t.get("name"), "image": str(write_image(out_dir / f"{stem}.png", v.image))}
    written.append(Path(rec["image"]))
    if "_raw.png" in suffixes:
        rec["raw"] = str(write_image(out_dir / f"{stem}_raw.png", v.raw))
        written.append(Path(rec["raw"]))
    if params.get("save_depth"):
        rec["depth"] = str(write_depth(out_dir / f"{stem}_depth.exr", v.depth.float().cpu()))
        written.append(Path(rec["depth"]))
    ref = v.reference
    rec["reference"] = None if ref is None else int(ref)
    rec["reference_name"] = None if ref is None else frames[int(ref)].get("name")
    rec["timings"] = {k: float(x) for k, x in dict(v.timings).items()}
    rec["enhanced"] = enhance
    rec["guard"] = getattr(v, "guard", None)  # why the raw render was kept, if it was
    if prefix is not None:
        rec["frame"] = int(t["frame"])
    return rec


TASKS = {
    "read_posed_images": task_read_posed_images,
    "write_transforms": task_write_transforms,
    "import_ply": task_import_ply,
    "export_ply": task_export_ply,
    "reconstruct": task_reconstruct,
    "render": task_render,
    "poses": task_poses,
}
