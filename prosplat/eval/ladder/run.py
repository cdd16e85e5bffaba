"""Scoring every rung of the ladder on every target of a scene.

For a scene, an input-view count V and an evaluation size S: V of the scene's input views are
picked by farthest-point sampling (as ``prosplat eval generator`` does), every view is resized
to S px high (antialiased; depth by nearest sampling), each rung reconstructs once and renders
every target, and each target is scored twice, on the whole image and inside its valid
region (pixels some input sees). One :class:`TargetScore` per (rung, target).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.data.rigs import pick_inputs
from prosplat.data.scene import SceneData, resize_views
from prosplat.eval.ladder.geometry import resize_depths, valid_mask
from prosplat.eval.ladder.rungs import Rung, SceneInputs, View
from prosplat.eval.ladder.stats import overlap_bin
from prosplat.metrics.depth import abs_rel, floater_share


@dataclass
class TargetScore:
    """One rung's scores on one target view (NaN where a metric does not apply)."""

    rung: str
    size: int
    views: int
    scene: str
    family: str
    scene_type: str  # the family, or the hard scene's name
    overlap: float  # mean pairwise input_overlap of the chosen inputs
    overlap_bin: str
    kind: str  # interpolation | extrapolation
    target: int  # view index in the scene folder
    psnr: float
    ssim: float
    lpips: float
    abs_rel: float
    floaters: float  # share of pixels with true depth drawn > 10 % in front of it
    valid_fraction: float  # of the target's pixels
    psnr_valid: float
    ssim_valid: float
    lpips_valid: float
    abs_rel_valid: float
    recon_s: float  # the rung's reconstruction of this scene (shared rungs: the same value)
    view_ms: float
    n_targets: int  # targets of the scene (amortised time = recon / n_targets + view)


METRICS = ("psnr", "ssim", "lpips", "abs_rel", "floaters")
VALID_METRICS = ("psnr_valid", "ssim_valid", "lpips_valid", "abs_rel_valid")


def chosen_overlap(scene: SceneData, idx: Sequence[int]) -> float:
    """Mean pairwise ``input_overlap`` (recorded by the renderer) of the input views ``idx``;
    NaN when the scene has none or a single view is chosen."""
    matrix = scene.meta.get("input_overlap")
    ins = scene.input_indices
    if matrix is None or len(idx) < 2 or len(matrix) != len(ins):
        return math.nan
    pos = [ins.index(i) for i in idx]
    pairs = [matrix[a][b] for k, a in enumerate(pos) for b in pos[k + 1 :]]
    return float(sum(pairs) / len(pairs))


def score_image(
    pred: Tensor,
    gt: Tensor,
    mask: Tensor | None = None,
    depth: Tensor | None = None,
    alpha: Tensor | None = None,
    gt_depth: Tensor | None = None,
) -> dict[str, float]:
    """PSNR/SSIM/LPIPS of ``pred`` [3,H,W] against ``gt`` (and AbsRel and the floater share,
    :func:`prosplat.metrics.depth.floater_share`, when depths are given);
    with ``mask`` [H,W] bool, the ``*_valid`` versions too. A metric that cannot be taken
    (LPIPS under 32 px, an empty or border-only mask) is NaN."""
    from prosplat.metrics import lpips, psnr, ssim

    pred = pred.clamp(0, 1).float()
    big = min(gt.shape[-2:]) >= 32
    out = {"psnr": float(psnr(pred, gt)), "ssim": float(ssim(pred, gt))}
    with torch.no_grad():
        out["lpips"] = float(lpips(pred, gt)) if big else math.nan
    geometry = depth is not None and gt_depth is not None and alpha is not None
    out["abs_rel"] = abs_rel(depth, gt_depth, alpha) if geometry else math.nan
    out["floaters"] = floater_share(depth, gt_depth, alpha) if geometry else math.nan
    if mask is not None:
        out["abs_rel_valid"] = (
            abs_rel(depth, torch.where(mask, gt_depth, torch.zeros_like(gt_depth)), alpha)
            if depth is not None and gt_depth is not None and alpha is not None
            else math.nan
        )
        for name, fn in (("psnr", psnr), ("ssim", ssim), ("lpips", lpips)):
            if name == "lpips" and not big:
                out["lpips_valid"] = math.nan
                continue
            try:
                with torch.no_grad():
                    out[f"{name}_valid"] = float(fn(pred, gt, mask))
            except ValueError:  # nothing valid (at least 5 px from the border, for SSIM)
                out[f"{name}_valid"] = math.nan
    return out


def _timed(fn, *args) -> tuple[object, float]:
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def run_rungs(
    rungs: Sequence[Rung], inputs: SceneInputs, cameras: Sequence[Camera]
) -> Iterator[tuple[Rung, int, View, float, float]]:
    """Every rung's view of every target camera: yields (rung, k, view, recon_s, view_s)
    with ``k`` the camera's index. Each rung reconstructs once (rungs with the same
    ``shares`` key reuse the first one's reconstruction and report its time).

    The loop every evaluation shares: ``prosplat eval ladder``, ``eval generator``, ``eval
    improve``, ``bench points`` and the demo all score their reference rows through it.
    """
    states: dict[str, tuple[object, float]] = {}
    inputs = replace(inputs, view_cameras=tuple(cameras))
    for rung in rungs:
        key = rung.shares or rung.name
        if key not in states:
            states[key] = _timed(rung.reconstruct, inputs)
        state, recon_s = states[key]
        for k, cam in enumerate(cameras):
            view, seconds = _timed(rung.view, state, cam, inputs)
            assert isinstance(view, View), f"ladder rung {rung.name!r} returned {type(view)}"
            yield rung, k, view, recon_s, seconds


def scene_inputs(
    images: Tensor, cameras: Sequence[Camera], depths: Tensor | None, idx: Sequence[int], near, far
) -> SceneInputs:
    """The views ``idx`` of ``images [A,3,H,W]`` / ``depths [A,H,W]`` as rung inputs."""
    return SceneInputs(
        images=images[list(idx)],
        cameras=[cameras[i] for i in idx],
        depths=None if depths is None else depths[list(idx)],
        near=float(near),
        far=float(far),
    )


def evaluate_scene(
    scene: SceneData,
    rungs: Sequence[Rung],
    views: int,
    size: int,
) -> list[TargetScore]:
    """Score every rung on every target of ``scene`` with ``views`` inputs at ``size`` px."""
    if scene.images.shape[-2] < size:
        raise ValueError(
            f"{scene.folder}: is {scene.images.shape[-2]} px high, cannot evaluate at {size} px "
            "(render it larger or lower --sizes)"
        )
    if scene.depths is None:
        raise ValueError(f"{scene.folder}: the ladder needs depth maps (valid regions, AbsRel)")
    idx = pick_inputs(scene, views)
    targets = scene.target_indices
    images, cams = resize_views(scene.images, scene.cameras, size)  # [A,3,S,W']
    depths = resize_depths(scene.depths, cams[0].width, cams[0].height)  # [A,S,W']
    inputs = scene_inputs(images, cams, depths, idx, scene.near[idx].min(), scene.far[idx].max())
    masks = {t: valid_mask(cams[t], depths[t], inputs.cameras, inputs.depths) for t in targets}
    overlap = chosen_overlap(scene, idx)
    meta = scene.meta
    common = dict(
        size=size,
        views=views,
        scene=scene.folder.name if scene.folder else "scene",
        family=str(meta.get("family", "?")),
        scene_type=str(meta.get("name") or meta.get("family", "?")),
        overlap=overlap,
        overlap_bin=overlap_bin(overlap),
        n_targets=len(targets),
    )
    rows = []
    cameras = [cams[t] for t in targets]
    for rung, k, view, recon_s, seconds in run_rungs(rungs, inputs, cameras):
        t = targets[k]
        s = score_image(view.image, images[t], masks[t], view.depth, view.alpha, depths[t])
        rows.append(
            TargetScore(
                rung=rung.name,
                kind=scene.target_kinds[t] or "target",
                target=t,
                valid_fraction=float(masks[t].float().mean()),
                recon_s=recon_s,
                view_ms=seconds * 1e3,
                **common,
                **s,
            )
        )
    return rows


def warm_up(scene: SceneData, rungs: Sequence[Rung], views: int, size: int) -> None:
    """Run the rungs that allow it once on one target, untimed: kernel compilation, weight
    loading and first-call allocations stay out of the measured times."""
    quick = [r for r in rungs if r.warmup]
    if quick:
        one = scene.select(scene.input_indices + scene.target_indices[:1])
        evaluate_scene(one, quick, views, size)
