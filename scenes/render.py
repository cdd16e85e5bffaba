"""Render one seeded scene with Cycles into a scene folder (bpy).

Run as ``python -m scenes.render --name room --seed 3 --out DIR ...`` for one scene, or with
``--jobs-from-stdin`` as a long-lived worker: it reads ``NAME SEED`` lines and answers each
with one ``PROSPLAT_DONE {json}`` or ``PROSPLAT_FAILED {json}`` line, so that the start-up of
Python, bpy and Cycles is paid once per worker, not once per scene (``prosplat scenes render``
runs one such worker per ``--workers`` and restarts one that crashes). Every scene starts from
Blender's factory settings (:func:`scenes.builders.build_scene`), so a scene renders the same
after another one as in a fresh process. The folder is written under a hidden temporary name
and renamed into place only when complete, so a scene folder that exists is a finished one and
an interrupted run leaves nothing half-made behind.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import bpy
import numpy as np
import torch
from mathutils import Matrix

from prosplat.convert.blender import blender_from_camera
from prosplat.convert.nerfstudio import Frame, write_transforms
from prosplat.core.camera import Camera
from prosplat.core.image_io import write_depth
from prosplat.data.overlap import overlap_matrix
from prosplat.data.render_jobs import DEFAULT_SIZE, add_camera_arguments, image_size
from prosplat.data.rigs import (
    arc_rig,
    choose_rig,
    draw_lens,
    draw_roll,
    roll_camera,
)
from prosplat.data.splits import split_of
from scenes.builders import SceneInfo, build_scene

#: Cycles' denoiser settings by name: (prefilter of the albedo and normal passes, OIDN quality).
#: "high" is Blender's default. "fast" skips the auxiliary passes' own denoising and runs OIDN's
#: balanced network: the colour render of a 128-px training view takes 0.7-0.8x the time, and
#: the image stays 30-38 dB from a 256-sample render, 0.1-0.9 dB below "high" (BENCHMARKS.md
#: "Faster training renders"), far above the error any model here learns from.
DENOISE_QUALITY = {"high": ("ACCURATE", "HIGH"), "fast": ("FAST", "BALANCED")}

BACKGROUND_DEPTH = 1e9  # Cycles writes ~1e10 where a ray hits nothing; we store 0 there
SKY_UP = (0.0, 0.0, 1.0)


def scene_folder_name(name: str, seed: int) -> str:
    return f"{name}_{seed:06d}"


def _width_height(size: int | tuple[int, int]) -> tuple[int, int]:
    """``N`` -> ``(N, N)``; ``(W, H)`` as it is."""
    if isinstance(size, int):
        return size, size
    width, height = size
    return int(width), int(height)


def configure_render(
    size: int | tuple[int, int],
    samples: int,
    denoise: bool,
    seed: int,
    threads: int,
    denoise_quality: str = "high",
) -> None:
    """Cycles on the CPU, plain sRGB output (Standard view transform, no dither), Z pass;
    ``size`` is ``N`` for N x N px images or ``(width, height)``; ``denoise_quality`` names the
    denoiser's settings (:data:`DENOISE_QUALITY`)."""
    if denoise_quality not in DENOISE_QUALITY:
        raise ValueError(f"denoise_quality {denoise_quality!r}: one of {sorted(DENOISE_QUALITY)}")
    width, height = _width_height(size)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_adaptive_sampling = False  # a fixed sample count: same seed, same pixels
    sc.cycles.use_denoising = denoise
    sc.cycles.denoising_prefilter, sc.cycles.denoising_quality = DENOISE_QUALITY[denoise_quality]
    sc.cycles.seed = seed
    sc.cycles.pixel_filter_type = "BOX"  # width set per pass in _render_view
    sc.render.resolution_x, sc.render.resolution_y = width, height
    sc.render.pixel_aspect_x = sc.render.pixel_aspect_y = 1.0  # square pixels: fx = fy
    sc.render.resolution_percentage = 100
    sc.render.film_transparent = False
    sc.render.dither_intensity = 0.0
    sc.render.threads_mode = "FIXED"
    sc.render.threads = max(1, threads)
    sc.render.use_persistent_data = True  # keep the BVH and shaders between the views
    sc.display_settings.display_device = "sRGB"
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    sc.view_layers[0].use_pass_z = True


def _place_camera(cam_obj, camera: Camera) -> None:
    p = blender_from_camera(camera)
    cam_obj.matrix_world = Matrix(p.matrix_world.tolist())
    cam_obj.data.lens = p.lens
    cam_obj.data.sensor_width = p.sensor_width
    cam_obj.data.sensor_height = p.sensor_height
    cam_obj.data.sensor_fit = p.sensor_fit
    cam_obj.data.shift_x = p.shift_x
    cam_obj.data.shift_y = p.shift_y
    cam_obj.data.clip_start = 0.01
    cam_obj.data.clip_end = 10_000.0


def _render_view(png: Path, exr_tmp: Path, samples: int, denoise: bool) -> np.ndarray:
    """Render the scene camera twice: colour, then depth.

    Colour: ``samples`` per pixel through a 1-px box filter (each pixel integrates its own
    footprint), saved as PNG through the Standard view transform. Depth: Cycles' Z pass takes
    one sample per pixel, wherever the filter put it; a second 1-sample render with a
    0.01-px filter puts it at the pixel centre, so the depth is exact where our cameras
    (and rasterizer) evaluate a pixel, not jittered by up to half a pixel.
    """
    import OpenImageIO as oiio

    sc = bpy.context.scene
    settings = sc.render.image_settings
    sc.cycles.samples, sc.cycles.use_denoising, sc.cycles.filter_width = samples, denoise, 1.0
    bpy.ops.render.render()
    settings.media_type = "IMAGE"
    settings.file_format = "PNG"
    settings.color_mode = "RGB"
    settings.color_depth = "8"
    bpy.data.images["Render Result"].save_render(filepath=str(png), scene=sc)

    sc.cycles.samples, sc.cycles.use_denoising, sc.cycles.filter_width = 1, False, 0.01
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    sc.render.filepath = str(exr_tmp)
    bpy.ops.render.render(write_still=True)
    inp = oiio.ImageInput.open(str(exr_tmp))
    if inp is None:
        raise RuntimeError(f"Blender wrote no readable EXR at {exr_tmp}: {oiio.geterror()}")
    try:
        sub = 0
        while inp.seek_subimage(sub, 0):
            names = list(inp.spec().channelnames)
            if any(n.endswith("Depth.Z") for n in names):
                px = inp.read_image(sub, 0, 0, len(names), oiio.FLOAT)
                z_channel = [i for i, n in enumerate(names) if n.endswith("Depth.Z")][0]
                depth = np.asarray(px)[..., z_channel]
                break
            sub += 1
        else:
            raise RuntimeError(f"{exr_tmp} has no Depth pass; is view_layer.use_pass_z on?")
    finally:
        inp.close()
    exr_tmp.unlink()
    return np.where(depth >= BACKGROUND_DEPTH, 0.0, depth).astype(np.float32)


def _remove_stale_partials(out: Path, name: str) -> None:
    """Delete leftovers of this scene from runs that were killed (their process is gone)."""
    for leftover in out.glob(f".{name}.partial-*"):
        try:
            pid = int(leftover.name.rsplit("-", 1)[1])
            os.kill(pid, 0)  # still running: another renderer owns it
        except (ValueError, ProcessLookupError):
            shutil.rmtree(leftover, ignore_errors=True)
        except PermissionError:
            pass


def render_scene(
    name: str,
    seed: int,
    out: Path,
    size: int | tuple[int, int] = DEFAULT_SIZE,
    n_inputs: int = 4,
    n_targets: int = 8,
    samples: int = 32,
    denoise: bool = False,
    threads: int | None = None,
    denoise_quality: str = "high",
    lens_mm: float | None = None,
    progress: bool = False,
    blend: Path | None = None,
    arc: int | None = None,
    roll: float = 0.0,
    lens_range: tuple[float, float] | None = None,
) -> Path:
    """Build and render scene ``name`` (a family, hard or capture scene) for ``seed`` into ``out``.

    Returns the scene folder. Skips (returns at once) when the folder already exists.
    ``size`` is ``N`` for N x N px images or ``(width, height)``: Blender's 36 mm sensor (fit
    AUTO) spans the longer side, so every camera has ``fx = fy = lens_mm / 36 * max(W, H)`` and
    its principal point at the image centre ``(W/2, H/2)``.
    ``progress`` prints one ``PROSPLAT_PROGRESS done total`` line per view to stdout (a parent
    process turns them into a progress bar: Blender's own log lines carry no count).
    ``blend`` also saves the built scene, with one camera object per rendered view, as a
    .blend file there (for artists to open; never replaces an existing file).
    ``arc`` N renders N views evenly spaced over the first quarter of the trajectory instead of a
    sparse rig (:func:`prosplat.data.rigs.arc_rig`: ``n_inputs`` inputs, the rest targets;
    ``n_targets`` is ignored): the overlapping sweep that the structure-from-motion tests use.
    ``roll`` D rolls each view's camera about its viewing axis by an angle uniform in [-D, D]
    degrees (:func:`prosplat.data.rigs.draw_roll`, keyed by the seed and the view's index;
    recorded as the frame's ``roll_deg``), as hand-held photos are rarely level; 0 leaves
    every camera exactly as before. ``lens_range`` (A, B) replaces the scene's lens by one
    drawn log-uniformly in [A, B] mm from the seed (:func:`prosplat.data.rigs.draw_lens`; the
    trajectory stays), for a range of focal lengths across scenes; not with ``lens_mm``.
    """
    if lens_range is not None and lens_mm is not None:
        raise ValueError("pass lens_mm or lens_range, not both")
    if roll < 0:
        raise ValueError(f"roll is a largest angle in degrees, >= 0; got {roll}")
    final = out / scene_folder_name(name, seed)
    if final.exists():
        return final
    out.mkdir(parents=True, exist_ok=True)
    _remove_stale_partials(out, final.name)
    tmp = out / f".{final.name}.partial-{os.getpid()}"
    (tmp / "images").mkdir(parents=True)
    (tmp / "depth").mkdir()
    t0 = time.perf_counter()
    try:
        info: SceneInfo = build_scene(name, seed)
        build_seconds = time.perf_counter() - t0
        if arc:
            rig = arc_rig(info.trajectory, arc, n_inputs)
        else:
            rig = choose_rig(info.trajectory, n_inputs, n_targets, seed)
        width, height = _width_height(size)
        configure_render(
            (width, height), samples, denoise, seed, threads or os.cpu_count() or 1, denoise_quality
        )
        sc = bpy.context.scene
        cam_obj = bpy.data.objects.new("prosplat_camera", bpy.data.cameras.new("prosplat_camera"))
        sc.collection.objects.link(cam_obj)
        sc.camera = cam_obj
        lens = draw_lens(seed, lens_range) if lens_range else lens_mm or info.lens_mm
        fx = lens / 36.0 * max(width, height)  # sensor fit AUTO
        views = [(i, "input", None) for i in rig.inputs]
        views += [(i, "target", k) for i, k in zip(rig.targets, rig.target_kinds)]
        views.sort()
        frames, cameras, depths, view_seconds = [], [], [], []
        for v, (traj_index, split, kind) in enumerate(views):
            eye, look = info.trajectory[traj_index]
            roll_deg = draw_roll(seed, v, roll)
            camera = roll_camera(Camera.look_at(eye, look, SKY_UP, fx, width, height), roll_deg)
            _place_camera(cam_obj, camera)
            t_view = time.perf_counter()
            depth = _render_view(
                tmp / "images" / f"{v:03d}.png", tmp / f"depth_{v:03d}_ml.exr", samples, denoise
            )
            write_depth(tmp / "depth" / f"{v:03d}.exr", torch.from_numpy(depth))
            view_seconds.append(round(time.perf_counter() - t_view, 3))
            if progress:
                print(f"PROSPLAT_PROGRESS {v + 1} {len(views)}", flush=True)
            valid = depth[depth > 0]
            near = float(valid.min()) if valid.size else 0.1
            far = float(valid.max()) if valid.size else 100.0
            extra = {
                "split": split,
                "depth_file_path": f"depth/{v:03d}.exr",
                "near": near,
                "far": far,
                "trajectory_index": traj_index,
            }
            if kind is not None:
                extra["target_kind"] = kind
            if roll:
                extra["roll_deg"] = roll_deg
            frames.append(Frame(camera, f"images/{v:03d}.png", extra))
            cameras.append(camera)
            depths.append(torch.from_numpy(depth))
        inputs = [i for i, f in enumerate(frames) if f.extra["split"] == "input"]
        overlap = overlap_matrix([cameras[i] for i in inputs], [depths[i] for i in inputs])
        off_diag = overlap[~torch.eye(len(inputs), dtype=torch.bool)]
        meta = {
            "near": min(f.extra["near"] for f in frames),
            "far": max(f.extra["far"] for f in frames),
            "seed": seed,
            "family": info.family,
            "name": name,
            "tags": list(info.tags),
            "split_set": split_of(seed),
            "bounds_min": list(info.bounds_min),
            "bounds_max": list(info.bounds_max),
            "input_overlap": overlap.tolist(),
            "mean_input_overlap": float(off_diag.mean()),
            "renderer": {
                "blender": bpy.app.version_string,
                "engine": "CYCLES",
                "device": "CPU",
                "samples": samples,
                "denoise": denoise,
                "denoise_quality": denoise_quality if denoise else None,
                "pixel_filter": "BOX 1px (colour), 0.01px (depth)",
                "view_transform": "Standard",
                "seconds": round(time.perf_counter() - t0, 2),
                "build_seconds": round(build_seconds, 3),
                "view_seconds": view_seconds,
            },
        }
        if roll:
            meta["renderer"]["max_roll_deg"] = roll
        if lens_range:
            meta["renderer"]["lens_range_mm"] = list(lens_range)
            meta["renderer"]["lens_mm"] = lens
        write_transforms(tmp / "transforms.json", frames, meta)
        if blend is not None:
            save_blend(blend, cam_obj, frames)
        _publish(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _publish(tmp: Path, final: Path) -> None:
    """Move a finished scene's folder ``tmp`` to ``final`` by one rename (atomic on one
    filesystem: the folder appears complete or not at all). When another process published
    the same scene while this one rendered it (two runs of one seed side by side, or a run
    started before a stopped one's last worker finished), the folder already there is kept
    and this copy dropped: both are the same seed's render, and the run goes on instead of
    failing the scene. A folder there without its transforms.json is no finished scene, and
    the error stands."""
    try:
        os.rename(tmp, final)
    except OSError:
        if not (final / "transforms.json").is_file():
            raise
        shutil.rmtree(tmp, ignore_errors=True)


def save_blend(path: Path, template, frames: list[Frame]) -> None:
    """Save the current scene with a camera object per frame (``input_000``, ``target_003``...)
    to ``path``; refuses to replace an existing file."""
    if path.exists():
        raise FileExistsError(f"{path} exists; not replacing it")
    sc = bpy.context.scene
    for v, frame in enumerate(frames):
        obj = template.copy()
        obj.data = template.data.copy()
        obj.name = obj.data.name = f"{frame.extra['split']}_{v:03d}"
        _place_camera(obj, frame.camera)
        sc.collection.objects.link(obj)
    sc.collection.objects.unlink(template)
    sc.camera = next(o for o in sc.collection.objects if o.name.startswith("input_"))
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True, compress=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Render one seeded scene with Cycles (bpy).")
    ap.add_argument(
        "--name", help="family (room, tabletop, open), hard scene or capture scene name"
    )
    ap.add_argument("--seed", type=int)
    ap.add_argument(
        "--jobs-from-stdin",
        action="store_true",
        help="render every 'NAME SEED' line of stdin, answering each with a PROSPLAT_DONE or "
        "PROSPLAT_FAILED line (instead of --name/--seed)",
    )
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument(
        "--size",
        type=int,
        default=None,
        metavar="N",
        help=f"N x N px images (default {DEFAULT_SIZE} when no --width/--height is given)",
    )
    ap.add_argument("--width", type=int, default=None, help="image width in px, with --height")
    ap.add_argument("--height", type=int, default=None, help="image height in px, with --width")
    ap.add_argument("--inputs", type=int, default=4)
    ap.add_argument("--targets", type=int, default=8)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--denoise", action="store_true")
    ap.add_argument("--denoise-quality", choices=sorted(DENOISE_QUALITY), default="high")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--progress", action="store_true", help="print PROSPLAT_PROGRESS lines")
    ap.add_argument("--blend", type=Path, default=None, help="also save the scene as a .blend")
    ap.add_argument(
        "--arc",
        type=int,
        default=None,
        help="render N views evenly spaced over a quarter of the trajectory (a dense, overlapping "
        "sweep for structure from motion; --targets is ignored)",
    )
    add_camera_arguments(ap)
    args = ap.parse_args(argv)
    try:
        size = image_size(args.size, args.width, args.height)
    except ValueError as e:
        ap.error(str(e))

    def one(name: str, seed: int) -> Path:
        return render_scene(
            name,
            seed,
            args.out,
            size,
            args.inputs,
            args.targets,
            args.samples,
            args.denoise,
            args.threads,
            denoise_quality=args.denoise_quality,
            progress=args.progress,
            blend=args.blend,
            arc=args.arc,
            roll=args.roll,
            lens_range=args.lens_range,
        )

    if args.jobs_from_stdin:
        if args.name is not None or args.seed is not None or args.blend is not None:
            ap.error("--jobs-from-stdin takes the scenes from stdin: drop --name/--seed/--blend")
        serve_jobs(sys.stdin, one)
        return 0
    if args.name is None or args.seed is None:
        ap.error("--name and --seed are required (or --jobs-from-stdin)")
    print(json.dumps({"folder": str(one(args.name, args.seed))}))
    return 0


def serve_jobs(lines, render_one) -> None:
    """Render each ``NAME SEED`` line with ``render_one(name, seed)`` and print one answer
    line per job (:mod:`prosplat.data.render_jobs`; blank lines are skipped). A scene that raises is
    reported and the worker goes on with the next one."""
    import traceback

    from prosplat.data.render_jobs import answer_line

    for line in lines:
        if not line.strip():
            continue
        try:
            name, seed_text = line.split()
            seed = int(seed_text)
        except ValueError:
            answer = {"line": line.strip(), "error": ["not a 'NAME SEED' line"]}
            print(answer_line(False, answer), flush=True)
            continue
        try:
            folder = render_one(name, seed)
            answer = {"name": name, "seed": seed, "folder": str(folder)}
            print(answer_line(True, answer), flush=True)
        except Exception:
            tail = traceback.format_exc().strip().splitlines()[-15:]
            print(answer_line(False, {"name": name, "seed": seed, "error": tail}), flush=True)


if __name__ == "__main__":
    sys.exit(main())
