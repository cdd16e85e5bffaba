"""Data curation for stage 2, as in the paper: the trained generator renders the target views
of training scenes, and each sample keeps the render, its MORI reference view with the
fundamental matrix to it, and the ground truth.

Both reference choices are stored (the paper's score and the geometric overlap), so one
curated file serves every ablation row. Curated sets are caches (``prosplat train curate``
writes one safetensors file), never committed.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from prosplat.core.checkpoints import read_checkpoint, write_checkpoint
from prosplat.data.dataset import load_source, scene_sources, source_name
from prosplat.data.rigs import pick_inputs
from prosplat.data.scene import resize_views
from prosplat.improve.epipolar import fundamental_matrix
from prosplat.improve.mori import select_reference
from prosplat.improve.warp import reference_warp
from prosplat.pipeline.enhance import (
    MAX_SPLAT_RADIUS,
    OTHER_VIEWS_OPACITY,
    painted_view_gaussians,
    render_as_viewed,
)
from prosplat.pipeline.refine import refine
from prosplat.render import render

CURATED_FORMAT = "prosplat-curated"
KINDS = ("interpolation", "extrapolation")
METHODS = ("paper", "overlap")

#: Per sample: images [S,3,H,W] (float16 in [0,1]), alpha [S,H,W] (float16), F [S,3,3],
#: warp [S,4,H,W] (float16: the reference warped through the rendered depth + validity),
#: kind/inputs/scene [S] int.
CuratedSet = dict[str, Tensor]


def curate_scene(
    model,
    scene,
    views: Sequence[int],
    refine_steps: int = 0,
    seed: int = 0,
    generator_height: int | None = None,
    splat_scale: float = 1.0,
    max_splat_radius: float | None = MAX_SPLAT_RADIUS,
    other_views_opacity: float = OTHER_VIEWS_OPACITY,
) -> dict[str, list[Tensor]]:
    """Samples of one scene for each input-view count in ``views`` (counts above the scene's
    input views are skipped). ``refine_steps > 0`` renders the refined scene instead (the
    generator's Gaussians pruned to the automatic budget, then :func:`prosplat.pipeline.refine.refine`
    for that many steps with its default options), so stage 2 can learn refined renders.
    ``generator_height``: the generator runs at most this high, as the pipeline runs it
    (:meth:`ProSplat.reconstruct`; None: the weights' trained size, 0: the views' size).
    ``splat_scale``: the Gaussians render with their scales multiplied by it, as
    ``render_view(..., splat_scale=)`` draws them for a model trained on such renders.
    ``max_splat_radius``: each target view leaves out the Gaussians it would draw wider than
    this fraction of its shorter side, as an enhanced view does at inference
    (:func:`prosplat.pipeline.enhance.oversized_splats`, judged before ``splat_scale``; the warp's
    reference depth comes from the same Gaussians); None draws every splat.
    ``other_views_opacity``: the render's colour favours the input MORI picks for the target,
    as every view at inference does (:func:`prosplat.pipeline.enhance.render_as_viewed`; 1: off)."""
    cols: dict[str, list[Tensor]] = {}

    def put(key: str, value: Tensor) -> None:
        cols.setdefault(key, []).append(value)

    for n in views:
        if n > len(scene.input_indices):
            continue
        idx = pick_inputs(scene, n)
        cams = [scene.cameras[i] for i in idx]
        near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
        images = scene.images[idx]
        if refine_steps:
            rec = model.reconstruct(
                images, cams, near, far, generator_height=generator_height
            )  # as the pipeline refines
            input_depths = rec.depths_for(images)  # None when the generator ran smaller
            gaussians = refine(
                rec.gaussians, images, cams, steps=refine_steps, seed=seed,
                depths=input_depths,
            ).gaussians  # fmt: skip
        else:  # the generator's every pixel-aligned Gaussian, unpruned
            rec = model.reconstruct(
                images, cams, near, far, budget="all", generator_height=generator_height
            )
            gaussians = rec.gaussians
            input_depths = rec.depths_for(images)  # MORI needs input-size maps
        drawn_all = gaussians.with_scale_factor(splat_scale)
        ref_depths: dict[int, Tensor] = {}  # input j -> every splat's depth there [H,W]
        for t in scene.target_indices:
            cam = scene.cameras[t]
            drawn = painted_view_gaussians(gaussians, cam, max_splat_radius, splat_scale)
            capped = len(drawn) < len(gaussians)  # this view leaves some splats out
            drawn = drawn if capped else drawn_all
            with torch.no_grad():  # as render_view draws it: favouring MORI's pick
                out = render_as_viewed(drawn, cam, cams, other_views_opacity, torch.zeros(3))
            put("render", out.rgb.half())
            put("alpha", out.alpha.half())
            put("target", scene.images[t].half())
            put("kind", torch.tensor(KINDS.index(scene.target_kinds[t] or "interpolation")))
            put("inputs", torch.tensor(n))
            # input j -> the drawn Gaussians' depth there [H,W]: shared by the targets that
            # draw every splat, this view's own when it leaves some out (both methods share it)
            depths_at = {} if capped else ref_depths
            for method in METHODS:
                j = select_reference(
                    cam, cams, method=method, target_depth=out.depth, input_depths=input_depths
                )
                put(f"ref_{method}", scene.images[idx[j]].half())
                put(f"F_{method}", fundamental_matrix(cam, cams[j]).float())
                if j not in depths_at:  # as inference warps: the Gaussians this view draws
                    with torch.no_grad():
                        depths_at[j] = render(drawn, cams[j]).depth
                warp = reference_warp(
                    drawn, cam, out.depth, out.alpha, images[j], cams[j], depths_at[j]
                )
                put(f"warp_{method}", warp.half())  # [4,H,W] for warp_input models
    return cols


def curate(
    model,
    root: str | Path,
    out: str | Path,
    views: Sequence[int] = (2, 4),
    overwrite: bool = False,
    progress: bool = True,
    command: str = "",
    refine_steps: int = 0,
    height: int | None = None,
    generator_height: int | None = None,
    splat_scale: float = 1.0,
    max_splat_radius: float | None = MAX_SPLAT_RADIUS,
    other_views_opacity: float = OTHER_VIEWS_OPACITY,
    first: int = 0,
    count: int | None = None,
) -> Path:
    """Curate every scene under ``root`` with the generator ``model`` (a ProSplat) into ``out``;
    ``refine_steps > 0``: renders of the refined scenes (see :func:`curate_scene`); ``height``:
    views resized to this height first (antialiased, as the ladder evaluates), so one set of
    128-px scenes serves a 64-px model; ``generator_height``, ``splat_scale``,
    ``max_splat_radius`` and ``other_views_opacity``: see :func:`curate_scene`.

    ``root``: a dataset folder, a scene pack (``.npz``, ``prosplat scenes pack``; depth is not
    needed) or several of them, comma-separated. ``first`` / ``count`` curate a slice of the
    scenes (sorted as listed), so several processes can share one set's scenes: the training
    loop takes the slices' files together (``--data a,b,...``)."""
    if int(refine_steps) != refine_steps or refine_steps < 0:
        raise ValueError(f"refine_steps must be an integer >= 0 (0: off), got {refine_steps}")
    if first < 0 or (count is not None and count < 1):
        raise ValueError(f"first must be >= 0 and count >= 1, got first={first}, count={count}")
    from tqdm import tqdm

    sources = scene_sources(str(root).split(","))
    if not sources:
        raise FileNotFoundError(f"no scenes (folders with transforms.json, or packs) in {root}")
    sources = sources[first : None if count is None else first + count]
    if not sources:
        raise ValueError(f"no scenes left after skipping the first {first} of {root}")
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass overwrite=True (--overwrite) to replace it")
    cols: dict[str, list[Tensor]] = {}
    size = None
    for s, source in enumerate(tqdm(sources, desc="curating", unit="scene", disable=not progress)):
        name = source_name(source)
        scene = load_source(source, load_depth=False)
        if height is not None:
            images, cameras = resize_views(scene.images, scene.cameras, height)
            scene = replace(scene, images=images, cameras=cameras)
        hw = tuple(scene.images.shape[-2:])
        if size is not None and hw != size:
            raise ValueError(
                f"{name} is {hw[1]}x{hw[0]} but earlier scenes are {size[1]}x{size[0]}; curate "
                "one image size per file"
            )
        size = hw
        part = curate_scene(
            model, scene, views, refine_steps=refine_steps, seed=s,
            generator_height=generator_height, splat_scale=splat_scale,
            max_splat_radius=max_splat_radius, other_views_opacity=other_views_opacity,
        )  # fmt: skip
        for k, v in part.items():
            cols.setdefault(k, []).extend(v)
        cols.setdefault("scene", []).extend([torch.tensor(s)] * len(part.get("render", [])))
    if not cols.get("render"):
        raise ValueError(
            f"no samples: the scenes under {root} have no target views or too few inputs"
        )
    tensors = {k: torch.stack(v) for k, v in cols.items()}
    meta = {
        "format": CURATED_FORMAT,
        "scenes": json.dumps([source_name(source) for source in sources]),
        "views": json.dumps(list(views)),
        "refine_steps": str(int(refine_steps)),
        "height": str(height or ""),
        "generator_height": str(generator_height or ""),
        "splat_scale": f"{splat_scale:g}",
        "max_splat_radius": "" if max_splat_radius is None else f"{max_splat_radius:g}",
        "other_views_opacity": f"{other_views_opacity:g}",
        # the generator's depth after the local sweep (prosplat.pipeline.depth_sweep) or as predicted
        "depth_sweep": "on" if getattr(model, "depth_sweep", None) is not None else "off",
        "command": command,
    }
    return write_checkpoint(tensors, out, meta, overwrite)


def load_curated(path: str | Path) -> CuratedSet:
    """A curated set written by :func:`curate` (images stay float16 until batched)."""
    tensors, meta = read_checkpoint(path, "curated stage-2 data")
    if meta.get("format") != CURATED_FORMAT:
        raise ValueError(
            f"{path} is not a curated stage-2 set; make one with `prosplat train curate`"
        )
    return tensors


def curated_alpha(data: CuratedSet, index: Tensor, device) -> Tensor | None:
    """The renders' alpha [S,1,H,W] float32 for the samples ``index``, or None for a set
    curated before alpha was stored."""
    if "alpha" not in data:
        return None
    return data["alpha"][index].float().to(device)[:, None]


def curated_warp(data: CuratedSet, index: Tensor, method: str, device) -> Tensor | None:
    """The warped references [S,4,H,W] float32 (RGB + validity) for the samples ``index``, or
    None for a set curated before the warp was stored."""
    key = f"warp_{method}"
    if key not in data:
        return None
    return data[key][index].float().to(device)


def curated_batch(data: CuratedSet, index: Tensor, method: str, device) -> tuple[Tensor, ...]:
    """(render, reference, F, target) float32 on ``device`` for the samples ``index``."""
    if method not in METHODS:
        raise ValueError(f"reference method must be one of {METHODS}, got {method!r}")
    return (
        data["render"][index].float().to(device),
        data[f"ref_{method}"][index].float().to(device),
        data[f"F_{method}"][index].float().to(device),
        data["target"][index].float().to(device),
    )
