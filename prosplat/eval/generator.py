"""``prosplat eval generator``: the generator and its baselines on held-out scenes, one table.

For every scene, every input-view count and every method, the scene's V input views are
reconstructed once (timed), pruned to the Gaussian budget, and every target view is
rendered (timed) and scored: PSNR / SSIM / LPIPS against Blender's image and depth AbsRel
against Blender's Z pass. Rows are grouped by method, view count and target kind
(interpolation / extrapolation), so speed can be read against error.

Beside the methods, the ladder's reference rows (:mod:`prosplat.eval.ladder`) score the same
targets: a flat image of the inputs' mean colour, the input MORI picks pasted, and Gaussians
at Blender's true input depth (the upper bound). Means carry bootstrapped 95 % intervals.
"""

from __future__ import annotations

import json
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.core.paths import fresh_folder, staged_folder
from prosplat.data.rigs import pick_inputs
from prosplat.data.scene import SceneData
from prosplat.geometry.budget import prune_pixel_aligned
from prosplat.metrics.depth import abs_rel
from prosplat.render import render

# A method maps (images [V,3,H,W], cameras, near, far) to (Gaussians, per-view depths [V,H,W]).
Method = Callable[[Tensor, list[Camera], float, float], tuple[Gaussians, Tensor]]


@dataclass
class Score:
    method: str
    views: int
    kind: str
    scene: str
    psnr: float
    ssim: float
    lpips: float
    abs_rel: float
    recon_s: float
    render_ms: float
    gaussians: int


def generator_method(model) -> Method:
    def run(images, cameras, near, far):
        # the generator as the pipeline runs it at the inputs' size (with its depth sweep)
        rec = model.reconstruct(images, cameras, near, far, budget="all", generator_height=0)
        return rec.gaussians, rec.depths

    return run


def refine_method(
    model,
    steps: int | None = None,
    seconds: float | None = None,
    budget: int | float | None = None,
    options=None,
) -> Method:
    """The generator, pruned to ``budget`` (None: automatic), then refined against the inputs
    for ``steps`` steps or ``seconds`` (:meth:`ProSplat.reconstruct`). Returns no
    depths: the refined Gaussians are already pruned and no longer pixel-aligned."""

    def run(images, cameras, near, far):
        rec = model.reconstruct(
            images, cameras, near, far, budget=budget, refine_steps=steps,
            refine_seconds=seconds, refine_options=options,
        )  # fmt: skip
        return rec.gaussians, None

    return run


def refine_label(steps: int | None = None, seconds: float | None = None) -> str:
    """The row name of a refined generator: ``generator+refine 300`` or ``... 5s``."""
    return f"generator+refine {steps}" if steps is not None else f"generator+refine {seconds:g}s"


def plane_sweep_method(n_depths: int = 64) -> Method:
    from prosplat.eval.baselines import plane_sweep_gaussians

    def run(images, cameras, near, far):
        g, depths, _ = plane_sweep_gaussians(images, cameras, near, far, n_depths=n_depths)
        return g, depths

    return run


def optimize_method(steps: int) -> Method:
    from prosplat.eval.baselines import optimize_gaussians

    def run(images, cameras, near, far):
        g, _ = optimize_gaussians(images, cameras, near, far, steps=steps)
        return g, None  # optimised Gaussians are no longer pixel-aligned: no dedup

    return run


@dataclass
class ResizedScene:
    """A scene at an evaluation size with its inputs picked (:func:`scene_at`): every view's
    ``images`` [A,3,H,W] and ``cameras``, the input indices ``inputs`` and the inputs' depth
    range."""

    images: Tensor
    cameras: list[Camera]
    inputs: list[int]
    near: float
    far: float

    @property
    def input_images(self) -> Tensor:
        return self.images[self.inputs]  # [V,3,H,W]

    @property
    def input_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.inputs]


def scene_at(scene: SceneData, views: int, size: int) -> ResizedScene:
    """``scene`` resized to ``size`` px high (antialiased) with ``views`` inputs picked as
    every evaluation picks them (:func:`pick_inputs`)."""
    from prosplat.data.scene import resize_views

    idx = pick_inputs(scene, views)
    images, cams = resize_views(scene.images, scene.cameras, size)
    near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
    return ResizedScene(images, cams, idx, near, far)


def score_view(
    method: str,
    views: int,
    kind: str | None,
    scene: str,
    pred: Tensor,
    gt: Tensor,
    recon_s: float,
    render_ms: float,
    gaussians: int,
    depth: Tensor | None = None,
    alpha: Tensor | None = None,
    gt_depth: Tensor | None = None,
) -> Score:
    """PSNR / SSIM / LPIPS (and depth AbsRel when depths are given) of one predicted view.

    LPIPS needs at least 32 px on each side (AlexNet's strides); smaller views score NaN.
    """
    from prosplat.metrics import lpips, psnr, ssim

    pred = pred.clamp(0, 1)
    with torch.no_grad():
        lp = float(lpips(pred, gt)) if min(gt.shape[1:]) >= 32 else float("nan")
    rel = (
        abs_rel(depth, gt_depth, alpha)
        if gt_depth is not None and depth is not None
        else float("nan")
    )
    return Score(
        method=method,
        views=views,
        kind=kind or "target",
        scene=scene,
        psnr=float(psnr(pred, gt)),
        ssim=float(ssim(pred, gt)),
        lpips=lp,
        abs_rel=rel,
        recon_s=recon_s,
        render_ms=render_ms,
        gaussians=gaussians,
    )


def evaluate_scene(
    scene: SceneData,
    methods: dict[str, Method],
    views: list[int],
    budget: int | float | None = None,
    references: tuple[str, ...] | list[str] = (),
) -> list[Score]:
    """Score every method on one scene for each input-view count, and the ladder's
    ``references`` rows (names from :data:`REFERENCE_ROWS`) on the same targets."""
    rows = []
    name = scene.folder.name if scene.folder else "scene"
    for n in views:
        idx = pick_inputs(scene, n)
        if references:
            rows += reference_scores(scene, idx, references)
        images = scene.images[idx]
        cams = [scene.cameras[i] for i in idx]
        near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
        for label, method in methods.items():
            t0 = time.perf_counter()
            g, depths = method(images, cams, near, far)  # methods that optimise need autograd
            g = g.detach()
            if depths is not None:
                g = prune_pixel_aligned(g, depths, cams, budget=budget)[0]
            recon = time.perf_counter() - t0
            for t in scene.target_indices:
                t1 = time.perf_counter()
                with torch.no_grad():
                    out = render(g, scene.cameras[t])
                render_ms = (time.perf_counter() - t1) * 1e3
                gt_depth = scene.depths[t] if scene.depths is not None else None
                rows.append(
                    score_view(
                        label,
                        n,
                        scene.target_kinds[t],
                        name,
                        out.rgb,
                        scene.images[t],
                        recon,
                        render_ms,
                        len(g),
                        out.depth,
                        out.alpha,
                        gt_depth,
                    )  # fmt: skip
                )
    return rows


#: the ladder rows ``prosplat eval generator`` / ``eval improve`` add beside their methods
REFERENCE_ROWS = ("flat", "paste", "true-depth")


def reference_scores(
    scene: SceneData,
    idx: list[int],
    names: tuple[str, ...] | list[str] = REFERENCE_ROWS,
    images: Tensor | None = None,
    cameras: list[Camera] | None = None,
) -> list[Score]:
    """The ladder's model-free reference rows (flat colour, MORI paste, true depth) on the
    targets of ``scene`` from the inputs ``idx``, as :class:`Score` rows beside the methods'.

    ``images``/``cameras`` (all views) default to the scene's own; pass resized ones to score
    at another size. "true-depth" is left out when the scene has no depth maps.
    """
    from prosplat.eval.ladder.geometry import resize_depths
    from prosplat.eval.ladder.run import run_rungs, scene_inputs
    from prosplat.eval.ladder.rungs import LadderContext, build_rungs

    images = scene.images if images is None else images
    cameras = scene.cameras if cameras is None else cameras
    depths = scene.depths
    if depths is None:
        names = [n for n in names if n != "true-depth"]
    else:
        depths = resize_depths(depths, cameras[0].width, cameras[0].height)
    rungs = build_rungs(list(names), LadderContext({"improve": False}), log=lambda _: None)
    near, far = scene.near[idx].min(), scene.far[idx].max()
    inputs = scene_inputs(images, cameras, depths, idx, near, far)
    targets = scene.target_indices
    name = scene.folder.name if scene.folder else "scene"
    rows = []
    for rung, k, view, recon_s, seconds in run_rungs(rungs, inputs, [cameras[t] for t in targets]):
        t = targets[k]
        rows.append(
            score_view(
                rung.name,
                len(idx),
                scene.target_kinds[t],
                name,
                view.image,
                images[t],
                recon_s,
                seconds * 1e3,
                view.info.get("gaussians", 0),
                view.depth,
                view.alpha,
                None if depths is None else depths[t],
            )  # fmt: skip
        )
    return rows


def summarise(rows: list[Score], seed: int = 0) -> list[dict]:
    """Mean scores (with bootstrapped 95 % intervals over targets: ``psnr_lo``/``psnr_hi``,
    likewise for ssim and lpips) and median times per (method, views, kind)."""
    from prosplat.eval.ladder.stats import bootstrap_ci

    keys = sorted({(r.method, r.views, r.kind) for r in rows}, key=lambda k: (k[1], k[2], k[0]))
    out = []
    for method, views, kind in keys:
        sub = [r for r in rows if (r.method, r.views, r.kind) == (method, views, kind)]

        def mean(field: str, sub=sub) -> float:
            vals = [getattr(r, field) for r in sub if getattr(r, field) == getattr(r, field)]
            return sum(vals) / len(vals) if vals else float("nan")

        recon_per_scene = {r.scene: r.recon_s for r in sub}
        intervals = {}
        for m in ("psnr", "ssim", "lpips"):
            ci = bootstrap_ci([getattr(r, m) for r in sub], seed=seed)
            intervals |= {f"{m}_lo": ci.lo, f"{m}_hi": ci.hi}
        out.append(
            intervals
            | dict(
                method=method,
                views=views,
                kind=kind,
                n=len(sub),
                psnr=mean("psnr"),
                ssim=mean("ssim"),
                lpips=mean("lpips"),
                abs_rel=mean("abs_rel"),
                recon_s=statistics.median(recon_per_scene.values()),
                render_ms=statistics.median(r.render_ms for r in sub),
                gaussians=mean("gaussians"),
            )
        )
    return out


def _with_ci(s: dict, m: str, digits: int) -> str:
    """``mean [lo, hi]``, or the bare mean when there is no interval (no finite values)."""
    if math.isnan(s.get(f"{m}_lo", math.nan)):
        return f"{s[m]:.{digits}f}"
    return f"{s[m]:.{digits}f} [{s[f'{m}_lo']:.{digits}f}, {s[f'{m}_hi']:.{digits}f}]"


def markdown_table(summary: list[dict]) -> str:
    """One line per (views, kind, method); PSNR / SSIM / LPIPS as mean [95 % interval]."""
    lines = [
        "| views | targets | method | n | PSNR ↑ [95 % CI] | SSIM ↑ | LPIPS ↓ | depth AbsRel ↓ "
        "| recon s | render ms/view | Gaussians |",
        "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in summary:
        lines.append(
            f"| {s['views']} | {s['kind']} | {s['method']} | {s['n']} | {_with_ci(s, 'psnr', 2)} | "
            f"{_with_ci(s, 'ssim', 3)} | {_with_ci(s, 'lpips', 3)} | {s['abs_rel']:.3f} | "
            f"{s['recon_s']:.2f} | {s['render_ms']:.1f} | {s['gaussians']:.0f} |"
        )
    return "\n".join(lines)


def write_scores(rows: list[Score], out: Path) -> int:
    """Print the summary table of ``rows`` and write ``summary.md`` and ``scores.json`` into a
    fresh folder at ``out`` (never over an earlier evaluation). Used by ``prosplat eval
    generator`` and ``prosplat eval improve``."""
    table = markdown_table(summarise(rows))
    print(table)
    out = fresh_folder(out, overwrite=False)
    with staged_folder(out) as partial:  # moved to ``out`` only when complete
        (partial / "scores.json").write_text(json.dumps([asdict(r) for r in rows], indent=1))
        (partial / "summary.md").write_text(table + "\n")
    print(f"wrote {out / 'summary.md'} and scores.json")
    return 0
