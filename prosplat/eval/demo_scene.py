"""A built-in analytic scene, laid out like a feed-forward generator's output.

Spheres in front of a back wall and a floor, ray-cast analytically from a few input cameras;
every input pixel becomes one Gaussian at its depth, sized to its pixel footprint and
coloured by a procedural texture. This is what a pixel-aligned generator (DepthSplat, stage
1 here) emits, so it is the layout the rasterizer is benchmarked on, and the scene
``make demo`` renders until the full pipeline exists. No files, no Blender: pure torch.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians

# (centre xyz, radius) of the spheres; the wall is z = 3, the floor y = 1 (OpenCV-like world:
# y down), so cameras sit at negative z looking towards +z.
_SPHERES = ((-0.7, 0.35, 1.2, 0.65), (0.8, 0.5, 1.8, 0.5), (0.1, -0.35, 2.2, 0.45))
_WALL_Z = 3.0
_FLOOR_Y = 1.0


def orbit_cameras(
    n: int,
    width: int,
    height: int,
    radius: float = 3.2,
    arc_deg: float = 50.0,
    fov_deg: float = 60.0,
) -> list[Camera]:
    """``n`` cameras on a horizontal arc in front of the scene, all looking at its centre."""
    fx = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    cams = []
    for i in range(n):
        a = math.radians(-arc_deg / 2 + arc_deg * (i / max(n - 1, 1)))
        eye = (radius * math.sin(a), -0.4, 1.5 - radius * math.cos(a))
        cams.append(Camera.look_at(eye, (0.0, 0.2, 1.6), (0.0, -1.0, 0.0), fx, width, height))
    return cams


def raycast(camera: Camera) -> tuple[Tensor, Tensor, Tensor]:
    """Analytic depth. Returns z-depth [H,W], world points [H,W,3], surface id [H,W] (long)."""
    dirs = camera.ray_directions(torch.float64)  # [H,W,3]
    o = camera.center.to(torch.float64)
    best = torch.full(dirs.shape[:2], math.inf, dtype=torch.float64)
    ident = torch.zeros(dirs.shape[:2], dtype=torch.long)
    for k, (cx, cy, cz, r) in enumerate(_SPHERES):
        oc = o - torch.tensor([cx, cy, cz], dtype=torch.float64)
        b = (dirs * oc).sum(-1)
        disc = b * b - (oc @ oc - r * r)
        s = -b - torch.sqrt(disc.clamp_min(0))
        hit = (disc > 0) & (s > 0) & (s < best)
        best, ident = torch.where(hit, s, best), torch.where(hit, k + 2, ident)
    for k, (axis, value) in enumerate(((2, _WALL_Z), (1, _FLOOR_Y))):
        s = (value - o[axis]) / dirs[..., axis]
        hit = (s > 0) & (s < best)
        best, ident = torch.where(hit, s, best), torch.where(hit, k, ident)
    points = o + dirs * best[..., None]
    zdepth = (points - o) @ camera.forward.to(torch.float64)
    return zdepth, points, ident


def texture(points: Tensor, ident: Tensor) -> Tensor:
    """Procedural colour [..., 3] in [0, 1]: checks on the wall and floor, stripes on spheres."""
    x, y, z = points.unbind(-1)
    checks = (torch.floor(x * 2) + torch.floor(y * 2) + torch.floor(z * 2)) % 2
    base = torch.tensor(
        [[0.8, 0.75, 0.65], [0.35, 0.45, 0.6], [0.85, 0.3, 0.2], [0.2, 0.7, 0.35], [0.9, 0.8, 0.2]],
        dtype=points.dtype,
    )[ident]
    stripes = 0.5 + 0.5 * torch.sin(12 * (x + 0.5 * y + 0.3 * z))
    shade = torch.where(ident < 2, 0.55 + 0.45 * checks, 0.6 + 0.4 * stripes)
    return (base * shade[..., None]).clamp(0, 1)


def pixel_aligned_gaussians(
    cameras: list[Camera], opacity: float = 0.95, seed: int = 0
) -> Gaussians:
    """One Gaussian per pixel of every camera, as a pixel-aligned generator would emit."""
    gen = torch.Generator().manual_seed(seed)
    parts = []
    for cam in cameras:
        zdepth, points, ident = raycast(cam)
        n = zdepth.numel()
        footprint = (zdepth / cam.fx).reshape(n, 1)  # one pixel's size at that depth
        scales = footprint * torch.tensor([[0.8, 0.8, 0.2]], dtype=torch.float64)
        quats = torch.nn.functional.normalize(
            torch.randn(n, 4, generator=gen, dtype=torch.float64), dim=1
        )
        op = opacity * (0.8 + 0.2 * torch.rand(n, generator=gen, dtype=torch.float64))
        parts.append(
            Gaussians.from_colors(
                points.reshape(n, 3), texture(points, ident).reshape(n, 3), scales, op, quats
            )
        )
    return Gaussians.cat(parts).to(dtype=torch.float32)


def demo_scene(size: int = 128, n_inputs: int = 2) -> tuple[Gaussians, list[Camera]]:
    """The demo's Gaussians (from ``n_inputs`` views at ``size``²) and those input cameras."""
    inputs = orbit_cameras(n_inputs, size, size)
    return pixel_aligned_gaussians(inputs), inputs
