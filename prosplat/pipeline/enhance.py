"""Rendering a camera and enhancing it with stage 2: the glue between rasterizer, MORI and the
improvement model, shared by :meth:`prosplat.ProSplat.render`, curation and evaluation.

The improvement model needs image sizes that are multiples of its stride (16 for ``tiny``);
any camera works here because the render and the reference are padded on the right and
bottom (edge replicate) and the result cropped back. Padding there leaves pixel coordinates,
and so the fundamental matrix, unchanged.

Any camera size: a view larger than the model's ``working_size`` (the largest view it runs on
directly: 256 for the shipped v22) is enhanced at that size, and only the change is upsampled
and added to the full-resolution render with its holes filled (``enhanced - filled render``
at the working size, :class:`EnhanceOptions` ``carry``). The render
keeps its own detail, the model sees textures near the scale it learned, memory stays bounded
by the working size whatever the camera (a 4K frame costs what a working-size one does), and
there are no tile seams.

The guard: enhancing a view that the Gaussians barely cover asks the model to invent a
picture, and a model that rewrites pixels the render is sure of has left its training
distribution. In both cases :func:`render_view` returns the raw render and says why
(``EnhancedView.guard``), instead of an invented image.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.improve.epipolar import fundamental_matrix
from prosplat.improve.mori import centre_distances, select_reference
from prosplat.improve.warp import warp_for
from prosplat.render import RenderOutput, render, render_pair
from prosplat.render.hole_fill import fill_colour
from prosplat.render.projection import check_max_radius

#: The splat scale (:meth:`Gaussians.with_scale_factor`) for the generator's *unrefined*
#: Gaussians in a raw view whose holes are filled (``fill_holes``). The generator sizes its
#: Gaussians to cover the gaps between them on black; with the gaps filled, half that
#: footprint is sharper. Chosen on the 8 validation scenes (data/val128, 64 px, 4 inputs:
#: filled 18.74 -> 19.23 dB); on the 24 test scenes +0.54 / +0.27 / +0.23 dB at 64 / 128 /
#: 256 px, every scene type gaining. Stage 2 v16, trained on full-size splats, is mixed on
#: them (+0.08 / -0.00 dB, some types lose); refined Gaussians, fitted at their own size,
#: gain nothing (BENCHMARKS "Splat scale").
SPLAT_SCALE = 0.5

#: The default of ``render_view(max_splat_radius=)``: splats a filled or enhanced view would
#: draw with a standard deviation wider than this fraction of its shorter side are left out.
#: On the 24 test scenes (generator v14, stage 2 v19, 4 inputs) it gains +0.04 / +0.03 dB
#: enhanced at 64 / 128 px and +0.10 / +0.05 raw filled, tabletops +0.18 / +0.11 (where
#: far-background Gaussians pass in front of the target cameras), LPIPS -0.002, and +0.05
#: after refine 100 + enhance at 64 px. It is level on the 8 validation scenes, where it was
#: chosen among 0.03-0.2 (0.05 and below cost the enhanced 64-px view). The demo's enhanced
#: views: 18.57 -> 18.82 dB (BENCHMARKS "Oversized splats").
MAX_SPLAT_RADIUS = 0.1

#: The default of ``render_view(other_views_opacity=)``: where the input views' Gaussians
#: overlap in a target, the colour comes mostly from the view MORI picks for it (the input
#: nearest the target), every other view's Gaussians entering it at a fraction of their
#: opacity that falls with the view's distance from the target (:func:`view_weights`: this
#: fraction for a view as near as the favoured one, 0 at the favoured input's own camera),
#: while the coverage, depth and holes stay those of all Gaussians at their own opacity. The
#: views disagree where their depth is wrong, and the nearest view's surfaces are the ones
#: that moved least to reach the target. Against every view alike, on the 24 test scenes
#: (generator v16, stage 2 v22, 4 inputs) the favoured colour gains about +0.4 dB on the
#: filled raw view and +0.1 enhanced, on the fox photos +0.5 enhanced. The fraction falling
#: with distance, at 0.5, gains over a constant 0.25 (BENCHMARKS "Favouring by distance"):
#: re-rendered input cameras come back as their own view drew them (28.6 / 27.8 -> 29.0 /
#: 29.0 dB at 64 / 128 px), and novel views gain a little; chosen on the 8 validation
#: scenes among 0.25, 0.5, 0.75 and 1 (BENCHMARKS "Views favour the nearest input" has the
#: constant's choice). 1 turns favouring off: every view alike, as ``render``.
OTHER_VIEWS_OPACITY = 0.5


def oversized_splats(gaussians: Gaussians, camera: Camera, max_radius: float) -> Tensor:
    """[N] bool: the Gaussians that ``camera`` draws with a standard deviation wider than
    ``max_radius`` times the view's shorter side, along the splat's widest direction (the
    rasterizer's own projection, :func:`prosplat.render.projection.project_gaussians`);
    Gaussians it does not draw (behind it) are never flagged.

    Why a view would leave them out: a pixel-aligned Gaussian is about one input pixel wide
    at its input's depth. Seen that large it lies far nearer this camera than any input
    saw it, which on the test scenes means a floater or another view's far background
    passing in front of this camera: a few such splats grey out a whole tabletop view
    (BENCHMARKS "Oversized splats"). Drawn, it could only blur; left out, the fill or stage 2
    paints the place from what surrounds it."""
    from prosplat.render.fused import project_gaussians_fused
    from prosplat.render.projection import project_gaussians, wider_than

    check_max_radius(max_radius)  # before the projection: a bad cap costs nothing
    g = gaussians.detach()
    # the fused kernel is the same float64 arithmetic at ~2.4x the speed (CPU only)
    p = (project_gaussians_fused if g.device.type == "cpu" else project_gaussians)(g, camera)
    return wider_than(p, camera, max_radius)


def _check_other_views_opacity(value) -> None:
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0 <= value <= 1):
        raise ValueError(f"other_views_opacity must be a number in [0, 1], got {value!r}")


def view_weights(
    camera: Camera, cameras: Sequence[Camera], favoured: int, other_views_opacity: float
) -> Tensor:
    """[V] float64: how much each of the ``cameras`` (the input views) counts in the colour of
    a view of ``camera`` that favours input ``favoured``: 1 for it, and for every other input
    j ``other_views_opacity · min(1, d_fav / d_j)``, d being the distance from ``camera``'s
    centre to each input camera's centre (a view at least as near as the favoured one gets
    ``other_views_opacity`` itself; distances within a millionth of the scene's extent count
    as equal, so inputs at one place, as on a tripod, stay alike even at their own centre).

    Why falling with distance: at an input's own camera (d_fav = 0) that input's image is
    the truth wherever its Gaussians draw, and any other view's colour there can only be
    worse; a view twice as far from the target as the favoured one has its surfaces moved
    twice as far to reach it. Unstructured lumigraph rendering (Buehler et al., 2001) weighs
    views by the same relative distance. Centres only: MORI's pick already accounts for the
    viewing direction."""
    if not 0 <= favoured < len(cameras):
        raise ValueError(f"favoured view {favoured} is not one of the {len(cameras)} cameras")
    _check_other_views_opacity(other_views_opacity)
    dist = centre_distances(camera, cameras)  # [V]
    # distances within a millionth of the scene's extent count as equal (the poses' rounding)
    extent = max(float(dist.max()), max(float(c.center.double().norm()) for c in cameras))
    eps = 1e-6 * extent + 1e-300
    ratio = ((dist[favoured] + eps) / (dist + eps)).clamp(max=1.0)  # [V]
    weights = other_views_opacity * ratio
    weights[favoured] = 1.0
    return weights


def render_favouring(
    gaussians: Gaussians,
    camera: Camera,
    weights: Tensor,
    background: Tensor | None = None,
    max_radius: float | None = None,
) -> RenderOutput:
    """``render(gaussians, camera)`` with the colour weighing the input views' Gaussians
    (``gaussians.views``) by ``weights [V]`` (each view's Gaussians enter the colour at that
    fraction of their opacity; :func:`view_weights`); alpha, depth and visibility are the
    plain render's, so the coverage (and what a fill or stage 2 treats as a hole) does not
    change. Where only views of weight 0 draw, or the weighted render draws almost nothing
    (alpha <= 1e-4), the colour is the plain render's. One projection, two composites
    (:func:`prosplat.render.render_pair`), which also leaves out the Gaussians wider than
    ``max_radius`` (None: none left out)."""
    if gaussians.views is None:
        raise ValueError("render_favouring needs Gaussians with views (the input view of each)")
    weights = torch.as_tensor(weights, dtype=torch.float64)
    if weights.dim() != 1 or bool(((weights < 0) | (weights > 1)).any()):
        raise ValueError(f"weights must be [V] in [0, 1], got {weights.tolist()}")
    g = gaussians
    if len(g) and int(g.views.max()) >= len(weights):
        raise ValueError(f"Gaussians of view {int(g.views.max())} but {len(weights)} weights")
    w = weights.to(g.opacities)[g.views]  # [N]
    out, out_w = render_pair(
        g, camera, g.opacities * w, background=background, max_radius=max_radius
    )
    bg = torch.zeros(3) if background is None else torch.as_tensor(background)
    bg = bg.to(out.rgb)[:, None, None]  # [3,1,1]
    a, a_w = out.alpha[None], out_w.alpha[None]  # [1,H,W]
    colour = (out_w.rgb - bg * (1 - a_w)) / a_w.clamp_min(1e-6)  # [3,H,W] un-premultiplied
    rgb = torch.where(a_w > 1e-4, colour * a + bg * (1 - a), out.rgb)
    return RenderOutput(rgb=rgb, alpha=out.alpha, depth=out.depth, visible=out.visible)


def painted_view_gaussians(
    gaussians: Gaussians,
    camera: Camera,
    max_splat_radius: float | None = MAX_SPLAT_RADIUS,
    splat_scale: float = 1.0,
) -> Gaussians:
    """The Gaussians a filled or enhanced view of ``camera`` draws: those it would draw wider
    than ``max_splat_radius`` of its shorter side left out (:func:`oversized_splats`, judged
    at their own size; None keeps them all), then their scales multiplied by
    ``splat_scale``. :func:`render_view` draws these, and stage-2 curation renders its
    training views from them, so the model learns what it is given."""
    if max_splat_radius is not None:
        gaussians = gaussians[~oversized_splats(gaussians, camera, max_splat_radius)]
    return gaussians.with_scale_factor(splat_scale)


def _favoured_view(
    gaussians: Gaussians, camera: Camera, cameras: Sequence[Camera] | None, weight: float
) -> int | None:
    """The input view whose Gaussians a view of ``camera`` favours (MORI's pick among
    ``cameras``), or None when nothing is favoured: ``weight`` 1, no input cameras, Gaussians
    without views, or views that do not index ``cameras`` (Gaussians of another input set)."""
    views = gaussians.views
    if weight == 1 or views is None or not cameras or len(gaussians) == 0:
        return None
    if int(views.max()) >= len(cameras):
        return None
    return select_reference(camera, list(cameras), method="paper")


def render_as_viewed(
    gaussians: Gaussians,
    camera: Camera,
    cameras: Sequence[Camera] | None,
    other_views_opacity: float = OTHER_VIEWS_OPACITY,
    background: Tensor | None = None,
    max_radius: float | None = None,
) -> RenderOutput:
    """The render every view starts from: :func:`render_favouring` of the input MORI picks
    among ``cameras``, the others weighed by :func:`view_weights`, when the Gaussians know
    their views and ``other_views_opacity`` < 1, else the plain ``render``.
    :func:`render_view` and stage-2 curation both draw this, so stage 2 learns from the
    renders it is given. ``max_radius``: the Gaussians :func:`oversized_splats` would flag
    are left out by the render's own projection (None: all drawn)."""
    favoured = _favoured_view(gaussians, camera, cameras, other_views_opacity)
    if favoured is None:
        return render(gaussians, camera, background=background, max_radius=max_radius)
    weights = view_weights(camera, cameras, favoured, other_views_opacity)
    return render_favouring(gaussians, camera, weights, background, max_radius)


@dataclass
class EnhancedView:
    """One rendered (and possibly enhanced) view.

    ``image`` [3,H,W] is the enhanced image (the raw render when not enhanced; its holes
    filled when :func:`render_view` was asked to); ``raw`` [3,H,W] the rasterizer's image;
    ``alpha``/``depth`` [H,W]; ``reference`` the index of the input camera MORI chose (None
    when not enhanced); ``timings`` in milliseconds.
    """

    image: Tensor
    raw: Tensor
    alpha: Tensor
    depth: Tensor
    reference: int | None
    timings: dict[str, float] = field(default_factory=dict)
    guard: str | None = None  # why the raw render was returned instead of the enhanced one


@dataclass(frozen=True)
class EnhanceOptions:
    """How stage 2 is applied to a view.

    Attributes:
        working_size: the longest side the model runs at; larger views are enhanced at this
            size and the change is carried up (module docstring). None: the model's own
            ``config.working_size``; 0: every view at its own size.
        guard: return the raw render when one of the two checks below fails.
        min_coverage: the least mean render alpha (fraction of the view the Gaussians
            cover) that is enhanced.
        max_departure: the largest mean absolute change (colour units, 0-1) the model may
            make on the pixels the render is confident about (alpha > ``confident_alpha``).
        confident_alpha: the alpha above which a rendered pixel counts as confident.
        carry: what a view larger than ``working_size`` carries the model's change onto.
            ``"filled"`` (the default): the render with its holes filled at full size
            (:func:`prosplat.render.hole_fill.fill_colour`), the change being the model's
            output less that filled render at the working size: the full-size render and
            fill keep the detail, stage 2 adds what it changes at its own scale. ``"raw"``:
            the render on black, the change including the model's own fill of the holes,
            upsampled: the full-size gaps between splats stay black under a blurred fill, a
            dotted lattice that stage 2 turned into a grid (at 512 px on the 6 test scenes
            the enhanced view scored 18.37 dB / LPIPS 0.662 so, 19.02 / 0.407 filled, the
            generator's filled raw view 18.71 / 0.395; BENCHMARKS.md, "Artist resolution").
    """

    working_size: int | None = None
    guard: bool = True
    min_coverage: float = 0.05
    max_departure: float = 0.25
    confident_alpha: float = 0.9
    carry: str = "filled"

    def __post_init__(self) -> None:
        if self.carry not in ("raw", "filled"):
            raise ValueError(f"carry must be 'raw' or 'filled', got {self.carry!r}")
        if self.working_size is not None and self.working_size < 0:
            raise ValueError(f"working_size must be >= 0 or None, got {self.working_size}")
        if not 0.0 <= self.min_coverage <= 1.0 or not 0.0 <= self.confident_alpha < 1.0:
            raise ValueError("min_coverage must be in [0, 1] and confident_alpha in [0, 1)")
        if not self.max_departure > 0:
            raise ValueError(f"max_departure must be > 0, got {self.max_departure}")


def departure(raw: Tensor, enhanced: Tensor, alpha: Tensor, confident_alpha: float) -> float:
    """Mean absolute change of ``enhanced`` from ``raw`` ([3,H,W]) over the pixels whose
    ``alpha [H,W]`` exceeds ``confident_alpha`` (0 when there are none)."""
    sure = alpha > confident_alpha  # [H,W]
    return float((enhanced - raw).abs().mean(0)[sure].mean()) if bool(sure.any()) else 0.0


def guard_reason(
    raw: Tensor, enhanced: Tensor, alpha: Tensor, options: EnhanceOptions
) -> str | None:
    """Why ``enhanced [3,H,W]`` should not replace ``raw [3,H,W]`` (``alpha [H,W]``), or None."""
    coverage = float(alpha.mean())
    if coverage < options.min_coverage:
        return f"coverage {coverage:.0%} < {options.min_coverage:.0%}: nothing to enhance"
    change = departure(raw, enhanced, alpha, options.confident_alpha)
    if change > options.max_departure:
        return (
            f"the model changed confident pixels by {change:.3f} on average "
            f"(> {options.max_departure}): out of its training distribution"
        )
    return None


def pad_to_multiple(images: Tensor, multiple: int) -> Tensor:
    """[B,3,H,W] -> [B,3,H',W'] with H', W' the next multiples, edge-replicated right/bottom."""
    h, w = images.shape[-2:]
    ph, pw = -h % multiple, -w % multiple
    if ph == 0 and pw == 0:
        return images
    return F.pad(images, (0, pw, 0, ph), mode="replicate")


def reference_at(image: Tensor, camera: Camera, width: int, height: int) -> tuple[Tensor, Camera]:
    """An input view resampled to the target's size (bilinear, antialiased) with its camera."""
    if (camera.width, camera.height) == (width, height):
        return image, camera
    resized = F.interpolate(
        image[None], size=(height, width), mode="bilinear", align_corners=False, antialias=True
    )[0]
    return resized, camera.resized(width, height)


def pasted_view(camera: Camera, images: Tensor, cameras: Sequence[Camera]) -> tuple[Tensor, int]:
    """The input MORI picks for ``camera`` among ``cameras`` (the paper's score, the
    reference stage 2 would borrow from), its image of ``images [N,3,H,W]`` resampled to
    ``camera``'s size: the simplest answer every view is measured against. Returns
    (image [3,H,W], input index)."""
    j = select_reference(camera, list(cameras), method="paper")
    image, _ = reference_at(images[j], cameras[j], camera.width, camera.height)
    return image, j


def enhance(
    improver,
    raw: Tensor,
    camera: Camera,
    reference_image: Tensor | None,
    reference_camera: Camera | None,
    dtype: torch.dtype = torch.float32,
    working_size: int | None = None,
    alpha: Tensor | None = None,
    warp: Tensor | None = None,
    carry: str = "filled",
    filled: Tensor | None = None,
) -> Tensor:
    """Run ``improver`` on one render ``raw [3,H,W]`` with its reference; returns [3,H,W].

    Views larger than ``working_size`` (None: the model's ``config.working_size``; 0: no
    limit) are enhanced at that size and the change is carried up (module docstring) onto
    the render with its holes filled at full size (``carry="filled"``; needs ``alpha``,
    without it the render as it is) or onto the render on black (``"raw"``;
    :class:`EnhanceOptions`).
    ``alpha [H,W]`` is the render's coverage, for models with ``config.alpha_input``;
    ``warp [4,H,W]`` the reference warped into the view and its validity
    (:func:`prosplat.improve.warp.reference_warp`), for models with ``config.warp_input``.
    ``dtype=torch.bfloat16`` runs under CPU/GPU autocast (the output is float32 again).
    ``filled [3,H,W]``: ``raw`` with its holes filled, when the caller has made it already
    (:func:`render_view` with ``fill_holes``); else ``carry="filled"`` makes it here.
    """
    if warp is None and improver.config.warp_input:
        raise ValueError(
            "this improvement model was trained with the warped reference (warp_input): pass "
            "warp=prosplat.improve.warp.reference_warp(...) or render through render_view / "
            "ProSplat.render, which compute it; without it the model's output is meaningless"
        )
    h, w = raw.shape[-2:]
    size = improver.config.working_size if working_size is None else working_size
    if size and max(h, w) > size:
        s = size / max(h, w)
        hs, ws = max(1, round(h * s)), max(1, round(w * s))
        parts = [raw] + [x.reshape(-1, h, w).to(raw) for x in (alpha, warp) if x is not None]
        stack = F.interpolate(
            torch.cat(parts)[None],
            size=(hs, ws),
            mode="bilinear",
            align_corners=False,
            antialias=True,
        )[0]  # [3 (+1 alpha) (+4 warp),hs,ws]
        small = stack[:3]
        small_alpha = stack[3] if alpha is not None else None
        small_warp = stack[-4:] if warp is not None else None
        base, small_base = raw, small
        if carry == "filled" and alpha is not None:
            a = alpha.to(raw)
            base = raw + (1 - a) * fill_colour(raw, a) if filled is None else filled  # [3,H,W]
            small_base = F.interpolate(
                base[None], size=(hs, ws), mode="bilinear", align_corners=False, antialias=True
            )[0]
        enhanced_small = _enhance_native(
            improver,
            small,
            camera.resized(ws, hs),
            reference_image,
            reference_camera,
            dtype,
            small_alpha,
            small_warp,
        )  # [3,hs,ws] on the model's device
        change = enhanced_small - small_base.to(enhanced_small.device, torch.float32)
        up = F.interpolate(change[None], size=(h, w), mode="bilinear", align_corners=False)[0]
        return (base.to(up.device, torch.float32) + up).clamp(0.0, 1.0)
    return _enhance_native(
        improver, raw, camera, reference_image, reference_camera, dtype, alpha, warp
    )


def _enhance_native(
    improver,
    raw: Tensor,
    camera: Camera,
    reference_image: Tensor | None,
    reference_camera: Camera | None,
    dtype: torch.dtype,
    alpha: Tensor | None = None,
    warp: Tensor | None = None,
) -> Tensor:
    """The model on ``raw [3,H,W]`` at its own size (padded to the model's multiple)."""
    h, w = raw.shape[-2:]
    m = improver.config.size_multiple
    device = next(improver.parameters()).device
    x = pad_to_multiple(raw[None].to(device), m)
    ref = fund = None
    if improver.config.reference:
        if reference_image is None or reference_camera is None:
            raise ValueError("this improvement model needs a reference view and its camera")
        ref_img, ref_cam = reference_at(reference_image.to(device), reference_camera, w, h)
        ref = pad_to_multiple(ref_img[None], m)
        fund = fundamental_matrix(camera, ref_cam)[None].to(device)  # float64: DWEA's precision
    a = None if alpha is None else pad_to_multiple(alpha[None, None].to(device, x.dtype), m)
    wp = None if warp is None else pad_to_multiple(warp[None].to(device, x.dtype), m)
    with torch.autocast(device.type, dtype=dtype, enabled=dtype != torch.float32):
        out = improver(x, ref, fund, a, wp)
    return out.float()[0, :, :h, :w]


def render_view(
    gaussians: Gaussians,
    camera: Camera,
    images: Tensor | None = None,
    cameras: Sequence[Camera] | None = None,
    improver=None,
    *,
    reference_method: str = "paper",
    background: Tensor | None = None,
    dtype: torch.dtype = torch.float32,
    options: EnhanceOptions | None = None,
    fill_holes: bool = False,
    fill_enhanced: bool = True,
    splat_scale: float = 1.0,
    max_splat_radius: float | None = MAX_SPLAT_RADIUS,
    other_views_opacity: float = OTHER_VIEWS_OPACITY,
) -> EnhancedView:
    """Render ``camera`` and, when ``improver`` is given, enhance it with the MORI reference
    chosen among ``cameras`` (whose images are ``images [N,3,H,W]``).

    ``options`` (default :class:`EnhanceOptions`) sets the working size and the guard; a
    guarded view returns the raw render as ``image`` with the reason in ``guard``.
    ``fill_holes``: the holes no input saw show the pull-push continuation of the render's
    own colours (:mod:`prosplat.render.hole_fill`) instead of black: a raw ``image`` (no
    ``improver``, or the guard kept it) is composited over that fill, an enhanced one is
    blended with it by the render's alpha (``α · enhanced + (1 − α) · fill``: stage 2 kept
    where the Gaussians cover the view). ``raw`` stays the render on black, which is what
    stage 2 takes. Not with a ``background``. ``fill_enhanced=False`` leaves an enhanced image
    as stage 2 made it, so the fill shows only in a raw or guarded view: the blend is level in
    PSNR but costs LPIPS on enhanced views, while a raw view on black loses 9-10 dB (BENCHMARKS
    "Raw views filled by default").
    ``splat_scale``: the Gaussians render with their scales multiplied by it
    (:meth:`Gaussians.with_scale_factor`; ``raw``, ``alpha``, ``depth`` and stage 2's input
    are that render). :data:`SPLAT_SCALE` suits the generator's unrefined Gaussians in a filled
    raw view; 1 (the default) is the Gaussians as they are.
    ``max_splat_radius``: Gaussians that this camera would draw wider than this fraction of
    its shorter side are left out of a view whose holes get painted, filled
    (``fill_holes``) or enhanced (:func:`oversized_splats`; :data:`MAX_SPLAT_RADIUS` by
    default); None draws them all. A raw view on black always draws them all: there the hole
    left would cost more than the blur (textureless scenes lose 1.3 dB).
    ``other_views_opacity``: with Gaussians that know their input view
    (``gaussians.views``) and the input ``cameras`` given, the colour favours the view MORI
    picks for ``camera``, every other view's Gaussians entering it at this fraction of their
    opacity (:func:`render_favouring`; :data:`OTHER_VIEWS_OPACITY`); 1 renders them alike."""
    options = options or EnhanceOptions()
    _check_other_views_opacity(other_views_opacity)
    if max_splat_radius is not None:  # checked even where a raw view on black ignores it
        check_max_radius(max_splat_radius, "max_splat_radius")
    as_given = gaussians
    painted = fill_holes or improver is not None  # the holes the cap leaves are painted
    cap = max_splat_radius if painted else None
    if fill_holes and background is not None:
        raise ValueError(
            "fill_holes fills the holes of a render on black; pass a background or "
            "fill_holes=True, not both"
        )
    # Gaussians at their own size are judged by the projection that draws them (one
    # projection, not two); scaled ones are judged before the scaling, on a subset
    drawn_cap = cap if splat_scale == 1 else None
    if splat_scale != 1:
        gaussians = painted_view_gaussians(gaussians, camera, cap, splat_scale)
    t0 = time.perf_counter()
    with torch.no_grad():
        out = render_as_viewed(
            gaussians, camera, cameras, other_views_opacity, background, drawn_cap
        )
    t1 = time.perf_counter()
    timings = {"render_ms": 1e3 * (t1 - t0)}
    fill = fill_colour(out.rgb, out.alpha) if fill_holes else None  # [3,H,W]
    shown = out.rgb if fill is None else out.rgb + (1 - out.alpha) * fill  # [3,H,W]
    if improver is None:
        return EnhancedView(shown, out.rgb, out.alpha, out.depth, None, timings)
    if images is None or cameras is None or len(cameras) == 0:
        raise ValueError("enhancing needs the input images and cameras (MORI picks a reference)")
    cameras = list(cameras)
    if images.ndim != 4 or images.shape[0] != len(cameras):
        raise ValueError(
            f"images must be [N,3,H,W] with one image per camera; got {list(images.shape)} for "
            f"{len(cameras)} cameras"
        )
    depth = out.depth if reference_method == "overlap" else None
    ref = select_reference(camera, cameras, method=reference_method, target_depth=depth)
    t2 = time.perf_counter()
    with torch.no_grad():
        # [4,H,W] or None; timed as part of the enhancement
        warped = gaussians  # the Gaussians the view drew, for the warp's reference depth
        if drawn_cap is not None and improver.config.warp_input:
            warped = painted_view_gaussians(gaussians, camera, cap)
        warp = warp_for(improver, warped, camera, out.depth, out.alpha, images[ref], cameras[ref])
        image = enhance(
            improver,
            out.rgb,
            camera,
            images[ref],
            cameras[ref],
            dtype,
            options.working_size,
            out.alpha,
            warp,
            options.carry,
            None if fill is None else shown,  # the fill render_view made already
        ).to(out.rgb.device)
    t3 = time.perf_counter()
    timings.update(mori_ms=1e3 * (t2 - t1), enhance_ms=1e3 * (t3 - t2))
    reason = guard_reason(out.rgb, image, out.alpha, options) if options.guard else None
    if reason is not None and fill is None and (cap is not None or gaussians is not as_given):
        with torch.no_grad():  # a guarded view on black: every Gaussian at its own size
            image = render_as_viewed(as_given, camera, cameras, other_views_opacity, background).rgb
    elif reason is not None:
        image = shown
    elif fill is not None and fill_enhanced:
        image = out.alpha * image + (1 - out.alpha) * fill
    return EnhancedView(image, out.rgb, out.alpha, out.depth, ref, timings, reason)
