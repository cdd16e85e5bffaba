"""The rungs of the evaluation ladder: every way of producing a target view that we compare.

From the bottom: a flat image of the inputs' mean colour; the input MORI picks, pasted; the
per-scene optimisation baseline; the generator's raw render; the enhanced view; the MORI pick
warped through the generator's depth; refinement; and the
upper bound, Gaussians at Blender's true input depth, raw and enhanced. A number means
something only between these.

A rung is two functions (:class:`Rung`): ``reconstruct`` runs once per scene and input set
(timed as the reconstruction), ``view`` once per target camera (timed per view). Rungs that
share a ``shares`` key reuse one reconstruction (the generator's Gaussians serve the raw and
the enhanced rung), so their time is counted once and their outputs differ only where they
should.

Adding a rung: write a factory ``(LadderContext) -> list[Rung]`` and register it::

    @register("my-rung")
    def my_rung(ctx: LadderContext) -> list[Rung]:
        if ctx.options.get("my_path") is None:
            raise SkipRung("my-rung needs --my-path")
        ...
        return [Rung("my rung", reconstruct, view, depth=True)]

A factory raises :class:`SkipRung` when it cannot run (no checkpoint given, no improvement
model); the ladder prints its message and goes on without it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.eval.ladder.geometry import true_depth_gaussians
from prosplat.geometry.consistency import DEFAULT_TAU, cross_view_check
from prosplat.geometry.depth_edges import edge_options
from prosplat.improve.mori import select_reference
from prosplat.improve.warp import reference_warp, warp_for
from prosplat.pipeline.enhance import MAX_SPLAT_RADIUS, OTHER_VIEWS_OPACITY


@dataclass(frozen=True)
class SceneInputs:
    """What every rung may use of one scene: the chosen input views at the evaluation size.

    ``images`` [V,3,H,W] in [0,1]; ``depths`` [V,H,W] Blender's z-depth (0 = sky), used only by
    the upper-bound rungs; ``near``/``far`` the scene's depth range.
    """

    images: Tensor
    cameras: list[Camera]
    depths: Tensor | None
    near: float
    far: float
    #: the cameras the rows will render (never their images): what a user asking for a set
    #: of views hands over, for the rungs that treat the views together (distill)
    view_cameras: tuple[Camera, ...] = ()


@dataclass
class View:
    """One predicted target view: ``image`` [3,H,W]; ``depth``/``alpha`` [H,W] when the rung
    has geometry (AbsRel is scored where alpha > 0.5), else None."""

    image: Tensor
    depth: Tensor | None = None
    alpha: Tensor | None = None
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Rung:
    """One ladder row.

    ``reconstruct(inputs) -> state`` once per scene (timed); ``view(state, camera, inputs) ->
    View`` per target (timed). ``shares``: rungs with the same key reuse one reconstruction
    (and its time). ``depth``: the rung predicts depth (scored as AbsRel).
    """

    name: str
    reconstruct: Callable[[SceneInputs], Any]
    view: Callable[[Any, Camera, SceneInputs], View]
    shares: str | None = None
    depth: bool = False
    warmup: bool = True  # run once untimed before measuring (False for slow rungs)


class SkipRung(Exception):  # noqa: N818 (a signal, not an error)
    """Raised by a rung factory that cannot run; its message says why and what would fix it."""


@dataclass
class LadderContext:
    """What factories build rungs from: ``options`` (command-line values such as
    ``generator``, ``improve``, ``opt_steps``, ``depthsplat``, ``budget``, ``dtype``) and the
    models, loaded once on first use and shared by every rung."""

    options: dict[str, Any] = field(default_factory=dict)
    _model: Any = None
    _improvers: dict[str, Any] | None = None

    @property
    def model(self):
        """The ProSplat model (generator + improvement model when one exists)."""
        if self._model is None:
            from prosplat.pipeline.model import ProSplat

            self._model = ProSplat.from_pretrained(
                self.options.get("generator"),
                improve=self.options.get("improve"),
                depth_sweep=False if self.options.get("no_depth_sweep") else None,
            )
            self._model.full_res_gaussians = not self.options.get("low_res_gaussians")
            if (edges := self.options.get("depth_edges")) is not None:
                self._model.depth_edges = edge_options(edges)
            if (scale := self.options.get("gaussian_scale")) is not None:
                self._model.max_gaussian_scale = float(scale)
        return self._model

    def improver(self, rung: str):
        """The improvement model, or SkipRung naming ``rung`` when none is loaded (or the
        options say ``improve=False``: then no model is loaded at all)."""
        if self.options.get("improve") is False or self.model.improver is None:
            raise SkipRung(f"{rung}: no improvement model (pass --improve PATH)")
        return self.model.improver

    def improvers(self, rung: str) -> dict[str, Any]:
        """``{suffix: improvement model}`` for every enhanced row: ``""`` for the main one
        (:meth:`improver`), then ``" (LABEL)"`` for each ``compare_improve`` entry
        ``LABEL=PATH`` (``--compare-improve``), so that several stage-2 models are scored on
        the same reconstructions in one run. Empty when there is neither."""
        if self._improvers is None:
            from prosplat.improve.io import load_improver

            extra = {}
            for spec in self.options.get("compare_improve") or []:
                label, _, path = str(spec).rpartition("=")
                if not label or not path:
                    raise ValueError(f"--compare-improve {spec!r} is not LABEL=PATH")
                extra[f" ({label})"] = load_improver(path).to(self.model.device).eval()
            self._improvers = extra
        try:
            main = {"": self.improver(rung)}
        except SkipRung:
            main = {}
        return main | self._improvers


Factory = Callable[[LadderContext], list[Rung]]
#: name -> factory, in ladder order (bottom first); :func:`register` adds to it
REGISTRY: dict[str, Factory] = {}


def register(name: str) -> Callable[[Factory], Factory]:
    """Decorator: add a rung factory to :data:`REGISTRY` under ``name`` (``--rows`` names)."""

    def add(factory: Factory) -> Factory:
        if name in REGISTRY:
            raise ValueError(f"a ladder rung {name!r} is already registered")
        REGISTRY[name] = factory
        return factory

    return add


def build_rungs(
    names: list[str], ctx: LadderContext, log: Callable[[str], None] = print
) -> list[Rung]:
    """The rungs of the registered factories ``names`` (in registry order); skipped factories
    are reported through ``log``. Raises ValueError for an unknown name."""
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise ValueError(f"unknown ladder rows {unknown}; choose from {', '.join(REGISTRY)}")
    rungs = []
    for name in (n for n in REGISTRY if n in names):
        try:
            rungs += REGISTRY[name](ctx)
        except SkipRung as e:
            log(f"skipping ladder row {name}: {e}")
    return rungs


# ---- the trivial answers -------------------------------------------------------------------


def flat_image(images: Tensor, height: int, width: int) -> Tensor:
    """[3,height,width] filled with the mean colour of every input pixel (``images`` [V,3,H,W])."""
    return images.mean(dim=(0, 2, 3))[:, None, None].expand(3, height, width).clone()


def paste_image(camera: Camera, inputs: SceneInputs) -> tuple[Tensor, int]:
    """The input view MORI picks for ``camera`` (the paper's score, the same choice stage 2
    makes), resampled to the target's size; returns (image [3,H,W], input index)."""
    from prosplat.pipeline.enhance import pasted_view

    return pasted_view(camera, inputs.images, inputs.cameras)


@register("flat")
def flat_rungs(ctx: LadderContext) -> list[Rung]:
    def view(mean: Tensor, cam: Camera, inputs: SceneInputs) -> View:
        return View(mean[:, None, None].expand(3, cam.height, cam.width).clone())

    return [Rung("flat colour", lambda inp: inp.images.mean(dim=(0, 2, 3)), view)]


@register("paste")
def paste_rungs(ctx: LadderContext) -> list[Rung]:
    def view(_: None, cam: Camera, inputs: SceneInputs) -> View:
        image, j = paste_image(cam, inputs)
        return View(image, info={"reference": j})

    return [Rung("MORI paste", lambda inp: None, view)]


# ---- Gaussians -----------------------------------------------------------------------------


def splat_view(
    gaussians, cam: Camera, inputs: SceneInputs, improver=None, dtype=None, fill_holes=False,
    splat_scale: float = 1.0, max_splat_radius: float | None = MAX_SPLAT_RADIUS,
    other_views_opacity: float = OTHER_VIEWS_OPACITY, options=None,
) -> View:  # fmt: skip
    """Render ``gaussians`` at ``cam`` and, with ``improver``, enhance it (MORI reference);
    ``fill_holes``: the raw render's holes filled (:mod:`prosplat.render.hole_fill`);
    ``splat_scale``: the Gaussians' scales multiplied by it; ``max_splat_radius``: splats
    wider than that fraction of the view left out; ``other_views_opacity``: the colour
    favours the input MORI picks; ``options`` how stage 2 is applied
    (:func:`prosplat.pipeline.enhance.render_view`)."""
    from prosplat.pipeline.enhance import render_view

    out = render_view(
        gaussians, cam, inputs.images, inputs.cameras, improver, dtype=dtype or torch.float32,
        fill_holes=fill_holes, splat_scale=splat_scale, max_splat_radius=max_splat_radius,
        other_views_opacity=other_views_opacity, options=options,
    )  # fmt: skip
    return View(
        out.image,
        out.depth,
        out.alpha,
        info={"reference": out.reference, "gaussians": len(gaussians)},
    )


def _dtype(ctx: LadderContext) -> torch.dtype:
    return torch.bfloat16 if ctx.options.get("bf16") else torch.float32


@register("optimize")
def optimize_rungs(ctx: LadderContext) -> list[Rung]:
    """Per-scene 3DGS optimisation (prosplat.eval.baselines.optimize) at each ``opt_steps``: its
    raw render (``3DGS opt N``) and, from the same fit, the render with its holes filled as
    the generator's filled rows are (``3DGS opt N filled``), so the two methods are scored
    alike whichever way the views are shown."""
    steps = ctx.options.get("opt_steps") or []
    if not steps:
        raise SkipRung("per-scene optimisation is slow; pass --opt-steps 300 1000 to run it")
    from prosplat.eval.baselines import optimize_gaussians

    def make(n: int) -> list[Rung]:
        def reconstruct(inp: SceneInputs):
            return optimize_gaussians(inp.images, inp.cameras, inp.near, inp.far, steps=n)[0]

        key = f"3DGS opt {n}"
        return [
            Rung(key, reconstruct, splat_view, key, depth=True, warmup=False),
            Rung(f"{key} filled", reconstruct, _filled_view(), key, depth=True, warmup=False),
        ]

    return [rung for n in steps for rung in make(int(n))]


def _generator_gaussians(ctx: LadderContext) -> Callable[[SceneInputs], Any]:
    """The generator's Gaussians as the pipeline makes them: run at most ``generator_size``
    px high (``--generator-size``; default the weights' trained size, 0 the evaluation
    size), pruned by the budget; they render at the evaluation size."""

    def reconstruct(inp: SceneInputs):
        return ctx.model.reconstruct(
            inp.images, inp.cameras, inp.near, inp.far, budget=ctx.options.get("budget"),
            generator_height=ctx.options.get("generator_size"),
        ).gaussians  # fmt: skip

    return reconstruct


@register("generator")
def generator_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's render (pruned by the automatic budget, as the pipeline ships it)."""
    return [Rung("generator", _generator_gaussians(ctx), splat_view, "generator", depth=True)]


def _enhanced_view(improver, dtype, options=None) -> Callable[[Any, Camera, SceneInputs], View]:
    def view(g, cam: Camera, inp: SceneInputs) -> View:
        return splat_view(g, cam, inp, improver, dtype, options=options)

    return view


@register("enhanced")
def enhanced_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's render enhanced by stage 2 (what ``ProSplat.render`` returns), one row
    per improvement model (:meth:`LadderContext.improvers`)."""
    improvers, dtype = ctx.improvers("enhanced"), _dtype(ctx)
    if not improvers:
        ctx.improver("enhanced")  # raises SkipRung with the reason
    recon = _generator_gaussians(ctx)
    return [
        Rung(f"enhanced{suffix}", recon, _enhanced_view(imp, dtype), "generator", depth=True)
        for suffix, imp in improvers.items()
    ]


def _filled_view(
    improver=None, dtype=None, options=None
) -> Callable[[Any, Camera, SceneInputs], View]:
    def view(g, cam: Camera, inp: SceneInputs) -> View:
        return splat_view(g, cam, inp, improver, dtype, fill_holes=True, options=options)

    return view


@register("carry")
def carry_rungs(ctx: LadderContext) -> list[Rung]:
    """Stage 2's change at its working size carried onto the full-size render on black
    (``EnhanceOptions(carry="raw")``, the way before 2026-11-29) instead of onto the render
    with its holes filled (the default): per improvement model ``enhanced ⇡raw`` and
    ``enhanced filled ⇡raw``, to pair with the ``enhanced`` and ``enhanced filled`` rows.
    The same as those at or below the working size."""
    from prosplat.pipeline.enhance import EnhanceOptions

    improvers, dtype = ctx.improvers("enhanced ⇡raw"), _dtype(ctx)
    if not improvers:
        ctx.improver("enhanced ⇡raw")  # raises SkipRung with the reason
    recon, options = _generator_gaussians(ctx), EnhanceOptions(carry="raw")
    rungs = []
    for suffix, imp in improvers.items():
        rungs += [
            Rung(f"enhanced ⇡raw{suffix}", recon, _enhanced_view(imp, dtype, options),
                 "generator", depth=True),
            Rung(f"enhanced filled ⇡raw{suffix}", recon, _filled_view(imp, dtype, options),
                 "generator", depth=True),
        ]  # fmt: skip
    return rungs


@register("fill")
def fill_rungs(ctx: LadderContext) -> list[Rung]:
    """The holes no input saw filled from the render's own colours
    (:mod:`prosplat.render.hole_fill`) instead of black: ``generator filled`` (the raw
    render composited over the fill; no learning, so it sits between the raw and the
    enhanced rows) and, per improvement model, ``enhanced filled`` (stage 2's view blended
    with the fill by the render's alpha), what ``ProSplat.render(..., fill_holes=True)``
    returns; and ``true depth filled``, the upper bound's raw render with the same fill (the
    scenes' depth maps needed), so the filled rows have their own bound."""
    recon, dtype = _generator_gaussians(ctx), _dtype(ctx)
    rungs = [Rung("generator filled", recon, _filled_view(), "generator", depth=True)]
    improvers = ctx.improvers("enhanced filled")  # {} without an improvement model
    rungs += [
        Rung(f"enhanced filled{suffix}", recon, _filled_view(imp, dtype), "generator", depth=True)
        for suffix, imp in improvers.items()
    ]

    def true_filled(state, cam: Camera, inp: SceneInputs) -> View:  # the same fill
        return true_depth_view(state, cam, inp, fill_holes=True)

    return rungs + [Rung("true depth filled", _true_depth, true_filled, "true depth", depth=True)]


def _consistent_gaussians(
    ctx: LadderContext, tau: float, votes: int
) -> Callable[[SceneInputs], Any]:
    """The generator's Gaussians as :func:`_generator_gaussians` makes them, less those
    ``votes`` other input views saw through (:func:`prosplat.geometry.consistency
    .cross_view_check`, margin ``tau``, on the reconstruction's own depth maps and cameras)."""

    def reconstruct(inp: SceneInputs):
        rec = ctx.model.reconstruct(
            inp.images, inp.cameras, inp.near, inp.far, budget=ctx.options.get("budget"),
            generator_height=ctx.options.get("generator_size"),
        )  # fmt: skip
        g = rec.gaussians
        check = cross_view_check(
            rec.depths, rec.cameras, tau, means=g.means, view_index=rec.view_index,
            min_votes=votes,
        )  # fmt: skip
        return g[check.keep.to(g.means.device)]

    return reconstruct


@register("consistent")
def consistent_rungs(ctx: LadderContext) -> list[Rung]:
    """Opt-in (issue 68, "Gaussians that the inputs agree on"): the generator's Gaussians
    less the floaters another input saw through
    (:func:`prosplat.geometry.consistency.cross_view_check`; the options
    ``consistency_tau``, default :data:`~prosplat.geometry.consistency.DEFAULT_TAU`, and
    ``consistency_votes``, default 1, set its margin and how many views must contradict;
    the command line has no flag for them yet), drawn as the ``fill`` rows draw
    theirs: ``generator consistent``, ``generator filled consistent`` and, per improvement
    model, ``enhanced consistent`` and ``enhanced filled consistent``, so they pair with the
    plain rows target by target. The pipeline does not run the check."""
    tau = float(ctx.options.get("consistency_tau") or DEFAULT_TAU)
    votes = int(ctx.options.get("consistency_votes") or 1)
    recon, dtype = _consistent_gaussians(ctx, tau, votes), _dtype(ctx)
    key = "consistent"
    rungs = [
        Rung("generator consistent", recon, splat_view, key, depth=True),
        Rung("generator filled consistent", recon, _filled_view(), key, depth=True),
    ]
    for suffix, imp in ctx.improvers("enhanced consistent").items():
        rungs += [
            Rung(f"enhanced consistent{suffix}", recon, _enhanced_view(imp, dtype), key,
                 depth=True),
            Rung(f"enhanced filled consistent{suffix}", recon, _filled_view(imp, dtype), key,
                 depth=True),
        ]  # fmt: skip
    return rungs


def _variant_rungs(
    ctx: LadderContext, rung: str, values: list[float], label: str, option: str,
    enhanced_filled: bool,
) -> list[Rung]:  # fmt: skip
    """Rows that draw the generator row's reconstruction with one of :func:`splat_view`'s
    options (``option``) at each of ``values``: ``generator filled <label><v>`` and, per
    improvement model, ``enhanced <label><v>`` (and ``enhanced filled`` with
    ``enhanced_filled``), so they pair with the plain rows target by target."""
    recon, dtype = _generator_gaussians(ctx), _dtype(ctx)
    improvers = ctx.improvers(rung)  # {} without an improvement model

    def make(name: str, v: float, improver=None, fill: bool = True) -> Rung:
        def view(g, cam: Camera, inp: SceneInputs) -> View:
            return splat_view(g, cam, inp, improver, dtype, fill_holes=fill, **{option: v})

        return Rung(f"{name} {label}{v:g}", recon, view, "generator", depth=True)

    rungs = []
    for v in values:
        rungs.append(make("generator filled", v))
        for suffix, imp in improvers.items():
            rungs.append(make(f"enhanced{suffix}", v, imp, fill=False))
            if enhanced_filled:
                rungs.append(make(f"enhanced filled{suffix}", v, imp))
    return rungs


@register("splat")
def splat_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's Gaussians drawn smaller (``--splat-scales``: their scales multiplied,
    :meth:`prosplat.Gaussians.with_scale_factor`) where the holes do not show black: rows
    ``generator filled ×S`` and, per improvement model, ``enhanced ×S`` and ``enhanced
    filled ×S``, on the same reconstruction as the ``generator`` row, so they pair with
    ``generator filled`` and ``enhanced`` target by target."""
    factors = [float(s) for s in ctx.options.get("splat_scales") or []]
    if not factors:
        raise SkipRung("no splat scale asked for; pass --splat-scales 0.5")
    return _variant_rungs(ctx, "splat", factors, "×", "splat_scale", enhanced_filled=True)


@register("cull")
def cull_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's Gaussians without the splats a target would see wider than a fraction
    of its shorter side (``--max-splat-radius``, :func:`prosplat.pipeline.enhance.oversized_splats`):
    rows ``generator filled ≤R`` and, per improvement model, ``enhanced ≤R``, on the same
    reconstruction as the ``generator`` row, so they pair with ``generator filled`` and
    ``enhanced`` target by target."""
    radii = [float(r) for r in ctx.options.get("max_splat_radius") or []]
    if not radii:
        raise SkipRung("no splat radius asked for; pass --max-splat-radius 0.1")
    return _variant_rungs(ctx, "cull", radii, "≤", "max_splat_radius", enhanced_filled=False)


@register("favour")
def favour_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's views with the other input views' Gaussians at up to a fraction of
    their opacity in the colour, less the farther they are (``--other-views-opacity``,
    :func:`prosplat.pipeline.enhance.view_weights` and :func:`~prosplat.pipeline.enhance.render_favouring`;
    1 draws every view alike, as before the default favoured the nearest): rows ``generator
    filled ◇W`` and, per improvement model, ``enhanced ◇W`` and ``enhanced filled ◇W``, on the
    same reconstruction as the ``generator`` row, so they pair with the default rows target
    by target."""
    weights = [float(w) for w in ctx.options.get("other_views_opacity") or []]
    if not weights:
        raise SkipRung("no other-views opacity asked for; pass --other-views-opacity 1")
    return _variant_rungs(ctx, "favour", weights, "◇", "other_views_opacity", enhanced_filled=True)


def warp_paste_view(g, cam: Camera, inp: SceneInputs) -> View:
    """The MORI reference warped into the target through the Gaussians' rendered depth
    (:func:`prosplat.improve.warp.warp_reference`, occlusion tested against their depth at
    the reference camera), the raw render where the warp is invalid: what a full-resolution
    reference injection could hand stage 2, with no learning."""
    from prosplat.render import render

    with torch.no_grad():
        out = render(g, cam)
    j = select_reference(cam, inp.cameras, method="paper")
    warp = reference_warp(g, cam, out.depth, out.alpha, inp.images[j], inp.cameras[j])
    valid = warp[3] > 0.5
    image = torch.where(valid[None], warp[:3], out.rgb)
    info = {"reference": j, "warp_valid": float(valid.float().mean())}
    return View(image, out.depth, out.alpha, info=info)


@register("warp")
def warp_rungs(ctx: LadderContext) -> list[Rung]:
    """The reference warped through the generator's depth (see :func:`warp_paste_view`)."""
    return [Rung("warp paste", _generator_gaussians(ctx), warp_paste_view, "generator", depth=True)]


def _refined_gaussians(
    ctx: LadderContext, steps: int | None, seconds: float | None = None
) -> Callable[[SceneInputs], Any]:
    """The generator's Gaussians as :func:`_generator_gaussians` makes them, then refined
    against the inputs (:mod:`prosplat.pipeline.refine`, shipped options) for ``steps`` or
    ``seconds``."""

    def reconstruct(inp: SceneInputs):
        return ctx.model.reconstruct(
            inp.images, inp.cameras, inp.near, inp.far, refine_steps=steps,
            refine_seconds=seconds, budget=ctx.options.get("budget"),
            generator_height=ctx.options.get("generator_size"),
        ).gaussians  # fmt: skip

    return reconstruct


@register("refine")
def refine_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's Gaussians refined against the inputs (:mod:`prosplat.pipeline.refine`, shipped
    options) for each ``--refine-steps`` count and ``--refine-seconds`` budget, raw and (with
    an improvement model) enhanced; the refinement is timed as the reconstruction."""
    steps = [int(n) for n in ctx.options.get("refine_steps") or []]
    seconds = [float(s) for s in ctx.options.get("refine_seconds") or []]
    if not steps and not seconds:
        raise SkipRung(
            "no refinement asked for; pass --refine-steps 100 300 or --refine-seconds 10"
        )
    improvers, dtype = ctx.improvers("refine enhanced"), _dtype(ctx)

    def make(label: str, n: int | None, sec: float | None) -> list[Rung]:
        reconstruct = _refined_gaussians(ctx, n, sec)
        raw = Rung(label, reconstruct, splat_view, label, depth=True, warmup=False)
        return [raw] + [
            Rung(f"{label} enhanced{suffix}", reconstruct, _enhanced_view(imp, dtype), label,
                 depth=True)
            for suffix, imp in improvers.items()
        ]  # fmt: skip

    rungs = [r for n in steps for r in make(f"refine {n}", n, None)]
    return rungs + [r for sec in seconds for r in make(f"refine {sec:g} s", None, sec)]


@register("distill")
def distill_rungs(ctx: LadderContext) -> list[Rung]:
    """The generator's Gaussians distilled (:mod:`prosplat.pipeline.distill`): every target camera
    enhanced, then the Gaussians refined against the inputs and those views for each
    ``--distill-steps`` count; rows ``distill N``: the distilled Gaussians' raw render, the
    consistent answer (enhancing it once more measured worse: BENCHMARKS "Distilled views").
    With ``--refine-steps`` too, rows ``refine R distill N`` start from the Gaussians refined
    R steps instead, as the add-on does when Refine Seconds and Distill Steps are both set.
    The enhancement of every view and the refinements are timed as the reconstruction."""
    steps = [int(n) for n in ctx.options.get("distill_steps") or []]
    if not steps:
        raise SkipRung("no distillation asked for; pass --distill-steps 800")
    improver, dtype = ctx.improver("distill"), _dtype(ctx)

    def make(n: int, refine: int | None) -> Rung:
        start = _generator_gaussians(ctx) if refine is None else _refined_gaussians(ctx, refine)

        def reconstruct(inp: SceneInputs):
            from prosplat.pipeline.distill import distill_enhanced

            g = start(inp)
            return distill_enhanced(
                g, inp.images, inp.cameras, inp.view_cameras, improver, steps=n, dtype=dtype
            ).gaussians

        label = f"distill {n}" if refine is None else f"refine {refine} distill {n}"
        return Rung(label, reconstruct, splat_view, depth=True, warmup=False)

    refines = [int(r) for r in ctx.options.get("refine_steps") or []]
    return [make(n, None) for n in steps] + [make(n, r) for r in refines for n in steps]


def _true_depth(inp: SceneInputs):
    """(surface Gaussians, sky Gaussians or None) at the inputs' true depth."""
    if inp.depths is None:
        raise ValueError("the true-depth rows need the scenes' depth maps")
    surface = true_depth_gaussians(inp.images, inp.depths, inp.cameras, part="surface")
    has_sky = bool((inp.depths <= 0).any())
    sky = true_depth_gaussians(inp.images, inp.depths, inp.cameras, part="sky") if has_sky else None
    return surface, sky


def true_depth_view(
    state, cam: Camera, inp: SceneInputs, improver=None, dtype=None, fill_holes=False
) -> View:
    """The surfaces rendered over the sky shell (rendered apart, so the depth and alpha scored
    are the surfaces': a 10 % leak of a sky 20x farther away would otherwise triple a pixel's
    depth), enhanced with the MORI reference when ``improver`` is given; ``fill_holes``: the
    raw view's holes (what neither surface nor sky covers) filled as the generator's are
    (:mod:`prosplat.render.hole_fill`), so the upper bound gets the same help."""
    from prosplat.pipeline.enhance import enhance
    from prosplat.render import render
    from prosplat.render.hole_fill import fill_holes as fill

    surface, sky = state
    with torch.no_grad():
        out = render(surface, cam)  # rgb over black, alpha, depth [H,W]
        raw, cover = out.rgb, out.alpha
        if sky is not None:
            back = render(sky, cam)
            raw = raw + (1 - out.alpha)[None] * back.rgb
            cover = out.alpha + (1 - out.alpha) * back.alpha
        if fill_holes:
            raw = fill(raw, cover)
    if improver is None:
        return View(raw, out.depth, out.alpha, info={"gaussians": len(surface)})
    j = select_reference(cam, inp.cameras, method="paper")
    warp = warp_for(improver, surface, cam, out.depth, out.alpha, inp.images[j], inp.cameras[j])
    with torch.no_grad():
        image = enhance(
            improver, raw, cam, inp.images[j], inp.cameras[j], dtype or torch.float32,
            alpha=out.alpha, warp=warp,
        )  # fmt: skip
    return View(image, out.depth, out.alpha, info={"reference": j, "gaussians": len(surface)})


@register("true-depth")
def true_depth_rungs(ctx: LadderContext) -> list[Rung]:
    """The upper bound: Gaussians at Blender's true input depth, raw and (with an improvement
    model) enhanced."""
    rungs = [Rung("true depth", _true_depth, true_depth_view, "true depth", depth=True)]
    dtype = _dtype(ctx)

    def make(improver) -> Callable[[Any, Camera, SceneInputs], View]:
        def view(state, cam: Camera, inp: SceneInputs) -> View:
            return true_depth_view(state, cam, inp, improver, dtype)

        return view

    return rungs + [
        Rung(f"true depth enhanced{suffix}", _true_depth, make(imp), "true depth", depth=True)
        for suffix, imp in ctx.improvers("true depth enhanced").items()
    ]


@register("depthsplat")
def depthsplat_rungs(ctx: LadderContext) -> list[Rung]:
    """DepthSplat's released checkpoint as stage 1, when a file is given (``--depthsplat``):
    our port (``prosplat.generator.depthsplat``) behind the ProSplat interface."""
    path = ctx.options.get("depthsplat")
    if not path:
        raise SkipRung("no DepthSplat checkpoint given (--depthsplat PATH)")
    from prosplat.pipeline.model import ProSplat

    model = ProSplat.from_pretrained(generator=path, improve=False)

    def reconstruct(inp: SceneInputs):
        return model.reconstruct(inp.images, inp.cameras, inp.near, inp.far, budget="all").gaussians

    return [Rung("DepthSplat", reconstruct, splat_view, depth=True)]
