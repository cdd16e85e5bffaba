"""Plane-sweep cost volume: how well each view's features agree with its neighbours' at each depth.

For reference view i and each of D depth candidates, the pixel centres of i are lifted to that
depth, projected into a neighbour j, and j's features are sampled there; the correlation
``<F_i, F_j->i> / sqrt(C)`` is high at the candidate where the two views see the same surface.

Conventions (DESIGN.md): OpenCV cameras, pixel (c, r) has its centre at (c + 0.5, r + 0.5).
``grid_sample(align_corners=False)`` puts -1 and +1 at the outer *edges* of the border pixels,
so a continuous pixel coordinate u at width w maps to ``u / w * 2 - 1`` with no half-pixel
correction; intrinsics must be the ones of the feature resolution (:func:`scale_intrinsics`).

Candidates are uniform in *inverse* depth: disparity (pixel shift between views) is linear in
1/z, so equal inverse-depth steps are equal pixel steps, and a far plane of 1e4 costs nothing.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor


def inverse_depth_candidates(near: Tensor, far: Tensor, num: int) -> Tensor:
    """[B] near, [B] far -> [B,D] depths, uniform in 1/z, ordered near to far."""
    t = torch.linspace(0.0, 1.0, num, dtype=near.dtype, device=near.device)  # [D]
    inv = (1.0 / near)[:, None] * (1 - t) + (1.0 / far)[:, None] * t  # [B,D]
    return 1.0 / inv


def scale_intrinsics(K: Tensor, sx: float, sy: float) -> Tensor:
    """[...,3,3] intrinsics for an image resized by (sx, sy); exact under the +0.5 convention
    because continuous pixel coordinates (edges at integers) scale linearly."""
    K = K.clone()
    K[..., 0, :] = K[..., 0, :] * sx
    K[..., 1, :] = K[..., 1, :] * sy
    return K


def camera_centers(w2c: Tensor) -> Tensor:
    """[...,4,4] world-to-camera -> [...,3] camera centres ``-R^T t``."""
    R, t = w2c[..., :3, :3], w2c[..., :3, 3:]
    return -(R.transpose(-1, -2) @ t)[..., 0]


def nearest_views(w2c: Tensor, k: int) -> Tensor:
    """[B,V,4,4] poses -> [B,V,k'] indices of each view's k' = min(k, V-1) nearest other views
    by camera-centre distance (ties broken by index, so coincident cameras are still valid)."""
    c = camera_centers(w2c)  # [B,V,3]
    v = c.shape[1]
    d = torch.cdist(c, c)  # [B,V,V]
    eye = torch.eye(v, dtype=torch.bool, device=c.device)
    d = d.masked_fill(eye, float("inf"))  # never match a view against itself
    order = torch.argsort(d, dim=-1, stable=True)  # [B,V,V]
    return order[..., : min(k, v - 1)]


def _relative_projection(K: Tensor, w2c: Tensor, nbr: Tensor) -> tuple[Tensor, Tensor]:
    """Per (reference i, neighbour j): A = K_j R_ji K_i^-1 [B,V,3,3] and b = K_j t_ji [B,V,3],
    so that pixel p of view i at depth z lands at ``z A p + b`` (homogeneous) in view j."""
    bsz = K.shape[0]
    bidx = torch.arange(bsz, device=K.device)[:, None]  # [B,1]
    Kj, w2c_j = K[bidx, nbr], w2c[bidx, nbr]  # [B,V,3,3], [B,V,4,4]
    rel = w2c_j @ torch.linalg.inv(w2c)  # [B,V,4,4] camera i -> camera j
    A = Kj @ rel[..., :3, :3] @ torch.linalg.inv(K)  # [B,V,3,3]
    b = (Kj @ rel[..., :3, 3:])[..., 0]  # [B,V,3]
    return A, b


def _candidate_depths(depths: Tensor, v: int, hw: int) -> Tensor:
    """[B,D] plane depths or [B,V,D,h,w] per-pixel depths -> [B,V',D,hw] (V' is 1 or V), the
    shape the warp broadcasts against."""
    if depths.ndim == 2:
        return depths[:, None, :, None]  # [B,1,D,1]
    if depths.ndim == 5 and depths.shape[1] == v and depths.shape[-2] * depths.shape[-1] == hw:
        return depths.flatten(-2)  # [B,V,D,hw]
    raise ValueError(
        f"cost volume: depths must be [B,D] planes or [B,V={v},D,h,w] per pixel, got "
        f"{list(depths.shape)}"
    )


@torch.no_grad()
def warp_grid(K: Tensor, w2c: Tensor, nbr: Tensor, depths: Tensor, h: int, w: int) -> Tensor:
    """Sampling grid of neighbour ``nbr`` for every reference pixel and candidate.

    Args:
        K: [B,V,3,3] intrinsics at the h x w resolution.
        w2c: [B,V,4,4] world-to-camera.
        nbr: [B,V] index of the neighbour view for each reference view.
        depths: [B,D] candidate depths (z along the reference optical axis), the same planes for
            every pixel; or [B,V,D,h,w], each pixel's own candidates (a cascade's band around a
            first estimate).
    Returns:
        [B,V,D,h,w,2] normalised coordinates for grid_sample(align_corners=False); points
        behind (or on) the neighbour's image plane are sent to (-2, -2), outside the image,
        so they sample zeros. No gradient: cameras and candidates are inputs, never learned
        (a band's depths come in detached), which lets the grid be built in place: 1.5x
        the speed for 32 candidates at 64x64 (BENCHMARKS "Faster sweeps").
    """
    A, b = _relative_projection(K, w2c, nbr)  # [B,V,3,3], [B,V,3]
    z = _candidate_depths(depths, K.shape[1], h * w)  # [B,V',D,hw]
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=K.dtype, device=K.device) + 0.5,
        torch.arange(w, dtype=K.dtype, device=K.device) + 0.5,
        indexing="ij",
    )
    pix = torch.stack([xs, ys, torch.ones_like(xs)], dim=0).view(3, h * w)  # [3,hw]
    a = A @ pix  # [B,V,3,hw]

    def coordinate(i: int) -> Tensor:  # row i of z·A·p + b: [B,V,D,hw]
        return torch.addcmul(b[:, :, i, None, None], z, a[:, :, None, i])

    depth_j = coordinate(2)  # [B,V,D,hw]
    # In front of camera j by a relative margin; the clamp keeps far-off points finite.
    behind = depth_j <= 1e-6 * z  # [B,V,D,hw]
    any_behind = bool(behind.any())  # rare: most neighbours see the whole frustum in front
    inv = depth_j.reciprocal_()
    if any_behind:
        inv.masked_fill_(behind, 0.0)
    grid = torch.stack([coordinate(0), coordinate(1)], dim=-1).mul_(inv[..., None])
    grid[..., 0].mul_(2 / w)
    grid[..., 1].mul_(2 / h)
    grid.sub_(1).clamp_(-2.0, 2.0)  # [B,V,D,hw,2]
    if any_behind:
        grid.masked_fill_(behind[..., None], -2.0)
    return grid.view(*grid.shape[:3], h, w, 2)


def correlate(feats: Tensor, warped: Tensor) -> Tensor:
    """[B,V,C,h,w] features and [B,V,C,D,h,w] the neighbour's warped to each candidate ->
    [B,V,D,h,w] their dot products over C.

    Multiplied and summed over C, not ``einsum("bvchw,bvcdhw->bvdhw")``: einsum contracts
    through per-pixel 1xC @ CxD matmuls, which first copy the warped volume into a
    pixel-major layout, forward and backward; that copy was a third of a 128-px training
    step's generator time, and this is about 2x faster (BENCHMARKS "The cost volume's
    correlation")."""
    if torch.is_grad_enabled() and (feats.requires_grad or warped.requires_grad):
        return (feats.unsqueeze(3) * warped).sum(2)
    # without gradients, one channel at a time into the [B,V,D,h,w] result: the C-fold
    # product is never stored, 4x the speed for 16 channels at 64x64
    out = torch.zeros_like(warped[:, :, 0])
    for c in range(feats.shape[2]):
        out.addcmul_(warped[:, :, c], feats[:, :, c, None])
    return out


#: Feature maps of at most this many pixels are correlated all pairs first
#: (:func:`sampled_correlation`); larger ones are warped, then correlated. Timed on one CPU
#: thread, 4 views, 32 candidates, without gradients (`benchmarks/sweep_speed.py`): the
#: all-pairs way was 4.5-10x faster for 48 channels at 16x16, 1.7-1.8x for 48 at 32x32 and
#: about level for 16 at 32x32 (0.7-1.3x over four runs), but 4x slower for 16 at 64x64, as
#: its matmul grows with the
#: square of the pixels (BENCHMARKS "Faster sweeps").
ALL_PAIRS_MAX_PIXELS = 1024


#: Candidate planes are warped and correlated in chunks whose largest temporary holds at
#: most this many values (2 MiB of float32; 2 planes of 16 channels at 64x64 for 4 views).
#: Why: whole, one neighbour's warp at that shape (the 128-px forward's fine volume) is 33.5
#: MB, past the 32 MiB up to which glibc reuses freed heap memory, so every call got fresh
#: pages from mmap and paid a page fault per 4 KiB; the image sweep's 10 MB ZNCC
#: statistics lost time to fresh pages too. Small chunks reuse warm memory and stay in
#: cache: the bare 128-px forward runs 1.31x faster (on a Xeon and an AMD EPYC) with the
#: same Gaussians bit for bit, and its training forward and backward 1.22x (BENCHMARKS
#: "Sweeps in plane chunks"). Raising glibc's mmap threshold instead
#: (MALLOC_MMAP_THRESHOLD_) gains about as much, which is how the cause was found.
PLANE_CHUNK_VALUES = 1 << 19


def planes_per_chunk(values_per_plane: int) -> int:
    """How many candidate planes of ``values_per_plane`` values fit :data:`PLANE_CHUNK_VALUES`
    (at least one)."""
    return max(1, PLANE_CHUNK_VALUES // max(1, values_per_plane))


def warped_correlation(feats: Tensor, src: Tensor, grid: Tensor) -> Tensor:
    """``<F_i(p), F_j(q)>`` for each reference pixel p and its candidates' points q: the
    neighbour's features ``src [B,V,C,h,w]`` bilinearly sampled at ``grid [B,V,D,h,w,2]``
    (zeros outside), then dotted with ``feats [B,V,C,h,w]`` -> [B,V,D,h,w]. Reads C channels
    at every one of the D·h·w points, a chunk of planes at a time (:data:`PLANE_CHUNK_VALUES`)."""
    b, v, c, h, w = feats.shape
    d = grid.shape[2]
    flat = src.reshape(b * v, c, h, w)
    per = planes_per_chunk(b * v * c * h * w)
    chunks = []
    for d0 in range(0, d, per):
        dc = min(per, d - d0)
        warped = F.grid_sample(
            flat,
            grid[:, :, d0 : d0 + dc].reshape(b * v, dc * h, w, 2),
            mode="bilinear",
            padding_mode="zeros",
            align_corners=False,
        ).view(b, v, c, dc, h, w)  # [B,V,C,Dc,h,w]
        chunks.append(correlate(feats, warped))  # [B,V,Dc,h,w]
    return chunks[0] if len(chunks) == 1 else torch.cat(chunks, dim=2)  # [B,V,D,h,w]


def sampled_correlation(feats: Tensor, src: Tensor, grid: Tensor) -> Tensor:
    """:func:`warped_correlation` the other way round, the same numbers to float rounding:
    first every reference pixel's dot product with every neighbour pixel (one batched
    matmul, [BV, hw, hw]), then each reference pixel's own correlation map sampled at its D
    points. Bilinear sampling is linear, so sampling the dot products equals dotting the
    sampled features, and a point outside is zero both ways. It trades the C-channel gather
    at D·h·w points for hw² multiply-adds in a matmul, which wins while hw is small
    (:data:`ALL_PAIRS_MAX_PIXELS`); memory grows as hw² per view."""
    b, v, c, h, w = feats.shape
    d = grid.shape[2]
    hw = h * w
    corr = torch.bmm(
        feats.reshape(b * v, c, hw).transpose(1, 2), src.reshape(b * v, c, hw)
    )  # [BV, hw (reference), hw (neighbour)]
    points = grid.permute(0, 1, 3, 4, 2, 5).reshape(b * v * hw, d, 1, 2)  # [BV·hw,D,1,2]
    sampled = F.grid_sample(
        corr.view(b * v * hw, 1, h, w),
        points,
        mode="bilinear",
        padding_mode="zeros",
        align_corners=False,
    )  # [BV·hw,1,D,1]
    return sampled.view(b, v, h, w, d).permute(0, 1, 4, 2, 3)  # [B,V,D,h,w]


def plane_sweep_cost_volume(
    feats: Tensor, K: Tensor, w2c: Tensor, depths: Tensor, neighbours: Tensor
) -> Tensor:
    """Correlation cost volume.

    Args:
        feats: [B,V,C,h,w] features of every view.
        K: [B,V,3,3] intrinsics at the feature resolution (see :func:`scale_intrinsics`).
        w2c: [B,V,4,4] world-to-camera.
        depths: [B,D] candidate depths, or [B,V,D,h,w] per pixel (see :func:`warp_grid`).
        neighbours: [B,V,k] views that each view is matched against (:func:`nearest_views`).
    Returns:
        [B,V,D,h,w] ``<F_i, F_j->i(d)> / sqrt(C)`` averaged over the k neighbours. With zero
        baseline every candidate warps to the same place, so the volume is flat along D
        (uninformative but finite); out-of-view samples correlate with zeros. Small feature
        maps are correlated all pairs first (:func:`sampled_correlation`), larger ones warped
        first (:func:`warped_correlation`): the same volume, whichever is faster.
    """
    b, v, c, h, w = feats.shape
    d = depths.shape[-3 if depths.ndim == 5 else 1]
    bidx = torch.arange(b, device=feats.device)[:, None]  # [B,1]
    cost = feats.new_zeros(b, v, d, h, w)
    k = neighbours.shape[-1]
    correlation = sampled_correlation if h * w <= ALL_PAIRS_MAX_PIXELS else warped_correlation
    for n in range(k):  # one neighbour at a time bounds memory to one warped volume
        nbr = neighbours[..., n]  # [B,V]
        grid = warp_grid(K, w2c, nbr, depths, h, w).to(feats.dtype)  # [B,V,D,h,w,2]
        cost = cost + correlation(feats, feats[bidx, nbr], grid)
    return cost / (k * math.sqrt(c))  # [B,V,D,h,w]
