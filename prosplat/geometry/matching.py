"""Matching images across views: ZNCC over a window, swept over depth planes, and the
winner-take-all that turns a cost curve into a depth and a confidence.

The product's depth sweep (:mod:`prosplat.pipeline.depth_sweep`), the generator's image cost
(:mod:`prosplat.generator.image_cost`) and the plane-sweep baseline
(:mod:`prosplat.eval.baselines.plane_sweep`) share these. ZNCC is invariant to gain and offset
between views, so it needs no photometric calibration, and it is zero (not random) on flat
patches, which keeps textureless regions at low confidence; ``COLOR_WEIGHT`` x the mean
absolute difference of the two windows' mean colours is added, since ZNCC ignores colour.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera

WINDOW = 5  # ZNCC window (pixels)
CONF_TAU = 0.1  # cost margin (in 1 - ZNCC units) at which confidence reaches 1 - 1/e
COLOR_WEIGHT = 1.0  # weight of the window-mean colour difference added to 1 - ZNCC
ZNCC_EPS = 1e-6  # added to var_ref * var_src: flat patches correlate to 0, not to noise
#: Depth candidates are warped in chunks of about this many pixels (4 planes at 128x128).
#: Small, because each chunk's temporaries (the warp, the five ZNCC statistics) are fresh
#: memory, and past a few MB fresh memory costs page faults: the pipeline's one pass at
#: 128 px (depth sweep on) ran 1.14x faster than with 2M-pixel chunks, at 256 px 1.08x, the
#: same Gaussians bit for bit (BENCHMARKS "Sweeps in plane chunks").
_CHUNK_PIXELS = 1 << 16


def check_inputs(images: Tensor, cameras: list[Camera], near: float, far: float) -> None:
    if not isinstance(images, Tensor) or images.ndim != 4 or images.shape[1] != 3:
        shape = list(images.shape) if isinstance(images, Tensor) else type(images).__name__
        raise ValueError(f"images must be a [V, 3, H, W] tensor, got {shape}")
    if not images.is_floating_point() or not torch.isfinite(images).all():
        raise ValueError("images must be finite floats in [0, 1]")
    v, _, h, w = images.shape
    if len(cameras) != v:
        raise ValueError(f"cameras must have one Camera per image: {len(cameras)} for {v} images")
    for i, cam in enumerate(cameras):
        if (cam.width, cam.height) != (w, h):
            raise ValueError(
                f"cameras[{i}] is {cam.width}x{cam.height} but the images are {w}x{h}; "
                "use Camera.resized to match"
            )
    if not (math.isfinite(near) and math.isfinite(far) and 0 < near < far):
        raise ValueError(f"near and far must satisfy 0 < near < far, got near={near}, far={far}")


def depth_candidates(near: float, far: float, n: int, dtype, device) -> Tensor:
    """[n] depths from near to far, uniform in inverse depth."""
    t = torch.linspace(0, 1, n, dtype=torch.float64)
    inv = 1 / near + (1 / far - 1 / near) * t
    return (1 / inv).to(dtype=dtype, device=device)


def _window_counts(n: int, r: int, like: Tensor) -> Tensor:
    """[n] how many of positions i-r..i+r lie in 0..n-1 (a border window's size)."""
    i = torch.arange(n, device=like.device)
    return ((i + r).clamp(max=n - 1) - (i - r).clamp(min=0) + 1).to(like.dtype)


def _box_sum(x: Tensor, r: int, dim: int) -> Tensor:
    """Sum over positions i-r..i+r along ``dim`` (zeros beyond it), by a running sum: two
    passes whatever the window, where a pooling kernel reads every window. The window's ends
    are sliced out of the running sum in place of padding it, and the dim is summed where it
    lies, not transposed last: 1.3x the speed of padding and transposing (the ZNCC
    statistics of a 64x64, 32-plane sweep)."""
    n = x.shape[dim]
    c = x.cumsum(dim)
    if n < 2 * r + 2:  # every window reaches past an end: pad instead
        pad = [0, 0] * (x.ndim - 1 - dim % x.ndim) + [1, 0]
        c = F.pad(c, pad)  # a zero before the first position
        hi = torch.arange(n, device=x.device).add(r + 1).clamp(max=n)
        lo = torch.arange(n, device=x.device).sub(r).clamp(min=0)
        return c.index_select(dim, hi) - c.index_select(dim, lo)
    out = torch.empty_like(c)
    part, run = out.narrow, c.narrow
    part(dim, 0, r + 1).copy_(run(dim, r, r + 1))  # windows cut by the start
    torch.sub(run(dim, 2 * r + 1, n - 2 * r - 1), run(dim, 0, n - 2 * r - 1),
              out=part(dim, r + 1, n - 2 * r - 1))  # fmt: skip
    end = part(dim, n - r, r)  # windows cut by the end: the total minus what lies before
    torch.sub(run(dim, n - 1, 1).expand_as(end), run(dim, n - 2 * r - 1, r), out=end)
    return out


def box_mean(x: Tensor, window: int = WINDOW) -> Tensor:
    """Mean over the ``window`` x ``window`` neighbourhood (odd; border windows shrink, not
    zero-pad) of the last two dimensions: ``avg_pool2d(x, window, 1, window // 2,
    count_include_pad=False)`` to float rounding (tests/eval/test_baselines.py), at under a third of its
    time (it was half of a sweep's)."""
    if window < 1 or window % 2 == 0:
        raise ValueError(f"box_mean: window must be odd and >= 1, got {window}")
    r = window // 2
    h, w = x.shape[-2:]
    y = _box_sum(_box_sum(x, r, -1), r, -2)
    count = _window_counts(h, r, x)[:, None] * _window_counts(w, r, x)[None, :]  # [H,W]
    return y.div_(count)


def patch_mean_var(ref: Tensor, window: int = WINDOW) -> tuple[Tensor, Tensor]:
    """[N,C,H,W] images -> the mean [N,C,H,W] and the variance [N,H,W] (summed over the
    channels: a patch's colours are one vector) of every ``window`` x ``window`` patch."""
    mu = box_mean(ref, window)
    # pooling is linear, so the channel sums are taken before it: 1 channel pooled, not C
    var = box_mean((ref * ref).sum(1, keepdim=True), window)[:, 0] - (mu * mu).sum(1)
    return mu, var


def window_zncc(
    warped: Tensor,
    ref: Tensor,
    mu_ref: Tensor,
    var_ref: Tensor,
    window: int = WINDOW,
    eps: float = ZNCC_EPS,
) -> tuple[Tensor, Tensor]:
    """ZNCC of every ``window`` x ``window`` patch of ``warped [N,C,...,H,W]`` (channels on
    dim 1, any dims between) against the reference's, whose ``ref``, ``mu_ref`` (broadcast
    against ``warped``) and ``var_ref`` (against ``warped`` without its channel dim) come from
    :func:`patch_mean_var`. Returns (ZNCC [N,...,H,W] in [-1, 1], the warped patches' mean
    [N,C,...,H,W]). ``eps`` is added to var_ref · var_warped: flat patches correlate to 0.
    The three statistics of ``warped`` go through one box filter."""
    c = warped.shape[1]
    stats = torch.cat(
        [warped, (warped * warped).sum(1, keepdim=True), (warped * ref).sum(1, keepdim=True)], 1
    )  # [N,C+2,...,H,W]
    stats = box_mean(stats, window)
    mu = stats[:, :c]
    var = (stats[:, c] - (mu * mu).sum(1)).clamp_min(0)
    cov = stats[:, c + 1] - (mu * mu_ref).sum(1)
    zncc = cov / torch.sqrt(var_ref.clamp_min(0) * var + eps)
    return zncc.clamp(-1, 1), mu


def zncc_cost(
    images: Tensor,
    cameras: list[Camera],
    ref: int,
    depths: Tensor,
    best_views: int | None = None,
) -> Tensor:
    """[D, H, W] matching cost ``1 - ZNCC + COLOR_WEIGHT * |mean colour difference|``.

    ``depths``: [D] candidate depths for every pixel (fronto-parallel planes) or [D,H,W] a
    candidate list per pixel (a local sweep around a depth map). The cost of a candidate is
    the mean over the source views in which it lands inside the image (in front of the
    camera); where none does, it is 1 (uncorrelated, no information). ``best_views``: per
    pixel, only the that many source views whose best candidate matches best are averaged
    (a view that sees another surface there, occluded, is left out); None: all of them.
    """
    v, _, h, w = images.shape
    d = depths.shape[0]
    dtype, device = images.dtype, images.device
    cam = cameras[ref]
    img = images[ref : ref + 1]  # [1,3,H,W]
    mu_r, var_r = patch_mean_var(img)  # [1,3,H,W], [1,H,W]
    uv = cam.pixel_centers(torch.float64).to(device)  # [H,W,2]
    sources = [s for s in range(v) if s != ref]
    select = best_views is not None and len(sources) > best_views
    if select:  # every source's cost is kept until the best-matching ones are known
        cost = torch.ones(len(sources), d, h, w, dtype=dtype, device=device)  # [S,D,H,W]
        valid_all = torch.zeros(len(sources), d, h, w, dtype=torch.bool, device=device)
    else:  # summed as the chunks come: memory stays a chunk's, whatever D and the views
        cost_sum = torch.zeros(d, h, w, dtype=dtype, device=device)
        n_valid = torch.zeros(d, h, w, dtype=dtype, device=device)
    # A pixel's point at depth z is C + z·ray (ray = its unprojection at z = 1 minus the
    # centre C), so in a source camera it is a + z·b with a = R_s·C + t_s and b = R_s·ray:
    # per candidate one multiply-add per coordinate, no matrix product (float64 once, here).
    centre = cam.center.to(device=device, dtype=torch.float64)  # [3]
    ray = cam.unproject(uv, torch.ones(h, w, dtype=torch.float64, device=device)) - centre
    along = []  # per source: a [3], b [H,W,3], fx, skew, cx, fy, cy
    for s in sources:
        src = cameras[s]
        R, t = src.R.to(ray), src.t.to(ray)
        a = (R @ centre + t).to(dtype)
        b = (ray @ R.T).to(dtype)
        K = src.K.to(torch.float64)
        along.append((a, b, *(float(K[i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2)))))
    chunk = max(1, _CHUNK_PIXELS // (h * w))
    for k0 in range(0, d, chunk):
        dk = depths[k0 : k0 + chunk].to(dtype)  # [C] or [C,H,W]
        dk = dk[:, None, None].expand(-1, h, w) if dk.ndim == 1 else dk
        for n, s in enumerate(sources):
            src = cameras[s]
            a, b, fx, skew, cx, fy, cy = along[n]
            x, y, z_s = (a[i] + dk * b[..., i] for i in range(3))  # [C,H,W] each
            z_safe = torch.where(z_s.abs() > 1e-12, z_s, torch.full_like(z_s, 1e-12))
            xn, yn = x / z_safe, y / z_safe
            gx = (fx * xn + skew * yn + cx) / src.width * 2 - 1  # align_corners=False
            gy = (fy * yn + cy) / src.height * 2 - 1
            valid = (z_s > 0) & (gx.abs() <= 1) & (gy.abs() <= 1)
            grid = torch.stack([gx, gy], -1).clamp(-2, 2).to(dtype)  # clamp keeps it finite
            warped = F.grid_sample(
                images[s : s + 1],
                grid.reshape(1, -1, w, 2),
                mode="bilinear",
                padding_mode="border",
                align_corners=False,
            )  # [1,3,C*H,W]
            warped = warped.reshape(3, -1, h, w).transpose(0, 1)  # [C,3,H,W]
            zncc, mu_s = window_zncc(warped, img, mu_r, var_r)  # [C,H,W], [C,3,H,W]
            c = 1 - zncc + COLOR_WEIGHT * (mu_s - mu_r).abs().mean(1)
            if select:
                cost[n, k0 : k0 + chunk] = c
                valid_all[n, k0 : k0 + chunk] = valid
            else:
                cost_sum[k0 : k0 + chunk] += c * valid
                n_valid[k0 : k0 + chunk] += valid.to(dtype)
    if select:
        best = torch.where(valid_all, cost, torch.full_like(cost, math.inf)).amin(1)  # [S,H,W]
        rank = best.argsort(0).argsort(0)  # [S,H,W] 0 = the view that matches best
        use = valid_all & (rank < best_views)[:, None]  # [S,D,H,W] the costs averaged
        cost_sum, n_valid = (cost * use).sum(0), use.sum(0).to(dtype)
    return torch.where(n_valid > 0, cost_sum / n_valid.clamp_min(1), torch.ones_like(cost_sum))


def winner_take_all(cost: Tensor) -> tuple[Tensor, Tensor]:
    """[D,H,W] cost -> the winning candidate [H,W] as a fractional index (a parabola through
    the best cost and its two neighbours, at most half a step off) and confidence [H,W].

    Confidence = ``(1 - exp(-margin / CONF_TAU)) * clamp(ZNCC_best, 0, 1)`` where the margin is
    the cost gap to the best candidate that is not the winner or its neighbours: a unique,
    well-correlated minimum scores near 1; flat (textureless) or repetitive (two minima)
    cost curves score near 0.
    """
    d = cost.shape[0]
    best_cost, k = cost.min(0)  # [H,W]
    idx = torch.arange(d, device=cost.device)[:, None, None]
    near_winner = (idx - k[None]).abs() <= 1
    second = torch.where(near_winner, torch.full_like(cost, math.inf), cost).amin(0)
    second = torch.where(torch.isfinite(second), second, best_cost)  # D <= 3
    margin = (second - best_cost).clamp_min(0)
    conf = (1 - torch.exp(-margin / CONF_TAU)) * (1 - best_cost).clamp(0, 1)

    km, kp = (k - 1).clamp_min(0), (k + 1).clamp_max(d - 1)
    c_m = cost.gather(0, km[None])[0]
    c_p = cost.gather(0, kp[None])[0]
    denom = c_m - 2 * best_cost + c_p
    interior = (k > 0) & (k < d - 1) & (denom > 1e-9)
    offset = torch.where(
        interior, 0.5 * (c_m - c_p) / denom.clamp_min(1e-9), torch.zeros_like(denom)
    )
    return k.to(cost.dtype) + offset.clamp(-0.5, 0.5), conf


def winner_take_all_depth(cost: Tensor, near: float, far: float) -> tuple[Tensor, Tensor]:
    """[D,H,W] cost of candidates uniform in inverse depth from near to far -> depth [H,W]
    (parabola-refined in inverse depth) and confidence [H,W] (:func:`winner_take_all`)."""
    k, conf = winner_take_all(cost)
    pos = k / max(cost.shape[0] - 1, 1)  # [0,1] in inverse depth
    inv = 1 / near + (1 / far - 1 / near) * pos
    return 1 / inv, conf
