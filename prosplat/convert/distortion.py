"""Lens distortion: OpenCV radial-tangential and fisheye models, and undistortion.

Points are *normalised* image coordinates ``(x, y) = (X/Z, Y/Z)`` of a camera-space point;
a distortion model maps the ideal (pinhole) ``(x, y)`` to the distorted ``(x_d, y_d)`` that
``K`` then turns into pixels, as OpenCV, COLMAP, nerfstudio and instant-ngp all do:

* ``opencv`` (radial-tangential; COLMAP ``SIMPLE_RADIAL``/``RADIAL``/``OPENCV``, nerfstudio
  and instant-ngp ``OPENCV``): with r² = x² + y²,
  ``radial = 1 + k1 r² + k2 r⁴ + k3 r⁶ + k4 r⁸`` and
  ``x_d = x·radial + 2 p1 x y + p2 (r² + 2x²)``, ``y_d = y·radial + p1 (r² + 2y²) + 2 p2 x y``.
  ``k4`` is the r⁸ term, nerfstudio's convention; OpenCV's rational model (COLMAP
  ``FULL_OPENCV`` with non-zero k4-k6) is refused by the readers.
* ``fisheye`` (COLMAP ``OPENCV_FISHEYE``/``SIMPLE_RADIAL_FISHEYE``/``RADIAL_FISHEYE``,
  nerfstudio ``OPENCV_FISHEYE``): θ = atan(r), ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``,
  ``(x_d, y_d) = (x, y)·θ_d / r``.

Undistorting an image resamples it onto a pinhole camera (:func:`undistorted_camera`) of the
same pixel size whose view lies wholly inside the distorted image's valid area: every output
pixel samples real input pixels, so there are no black borders for the generator to explain
(OpenCV's ``getOptimalNewCameraMatrix`` with ``alpha=0``). The pixel aspect (fx/fy) is kept and
the view is centred in the largest axis-aligned rectangle the input's undistorted border
encloses, so the principal point may move a little. The price: the input's outermost
(most distorted) pixels are cropped away.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera

__all__ = [
    "MODELS",
    "Distortion",
    "distort_points",
    "undistort_image",
    "undistort_points",
    "undistort_view",
    "undistorted_camera",
]

MODELS = ("opencv", "fisheye")
_THETA_MAX = 0.5 * math.pi - 1e-3  # fisheye rays at or beyond 90° have no pinhole image


@dataclass(frozen=True)
class Distortion:
    """A lens model: ``model`` in :data:`MODELS` and its coefficients (unused ones 0)."""

    model: str = "opencv"
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"distortion model must be one of {MODELS}, got {self.model!r}")
        for name in ("k1", "k2", "k3", "k4", "p1", "p2"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(
                    f"distortion coefficient {name} must be a finite number, got {v!r}"
                )
            object.__setattr__(self, name, float(v))
        if self.model == "fisheye" and (self.p1 or self.p2):
            raise ValueError("the fisheye model has no tangential terms; p1 and p2 must be 0")

    @property
    def is_identity(self) -> bool:
        """True for a model that does not move any point (all coefficients 0)."""
        return not any((self.k1, self.k2, self.k3, self.k4, self.p1, self.p2))


def distort_points(xy: Tensor, d: Distortion) -> Tensor:
    """[..., 2] ideal normalised coordinates -> [..., 2] distorted ones (see the module doc)."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if d.model == "fisheye":
        r = r2.sqrt()
        theta = torch.atan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (d.k1 + t2 * (d.k2 + t2 * (d.k3 + t2 * d.k4))))
        # θ_d / r -> 1 as r -> 0 (θ ≈ r there); avoid 0/0 at the centre
        scale = torch.where(r > 1e-12, theta_d / r.clamp_min(1e-12), torch.ones_like(r))
        return xy * scale[..., None]
    radial = 1 + r2 * (d.k1 + r2 * (d.k2 + r2 * (d.k3 + r2 * d.k4)))
    xd = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x)
    yd = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y
    return torch.stack([xd, yd], dim=-1)


def undistort_points(xy_d: Tensor, d: Distortion, iterations: int = 50) -> Tensor:
    """The inverse of :func:`distort_points` (Newton's method, float64 inside).

    Fisheye inverts θ_d(θ) per point, with θ kept below 90°; radial-tangential runs a 2-D
    Newton iteration from ``x = x_d`` with the Jacobian by central differences. Both converge
    to ~1e-12 for the distortions real lenses have (the map is monotonic over the image).
    """
    dtype = xy_d.dtype
    q = xy_d.double()
    if d.is_identity:
        return xy_d.clone()
    if d.model == "fisheye":
        rd = q.norm(dim=-1)
        theta = rd.clone().clamp(max=_THETA_MAX)
        for _ in range(iterations):
            t2 = theta * theta
            f = theta * (1 + t2 * (d.k1 + t2 * (d.k2 + t2 * (d.k3 + t2 * d.k4)))) - rd
            df = 1 + t2 * (3 * d.k1 + t2 * (5 * d.k2 + t2 * (7 * d.k3 + t2 * 9 * d.k4)))
            theta = (theta - f / torch.where(df.abs() > 1e-12, df, torch.ones_like(df))).clamp(
                0.0, _THETA_MAX
            )
        r = torch.tan(theta)
        scale = torch.where(rd > 1e-12, r / rd.clamp_min(1e-12), torch.ones_like(rd))
        return (q * scale[..., None]).to(dtype)
    x = q.clone()
    eps = 1e-7
    ex = torch.tensor([eps, 0.0], dtype=torch.float64)
    ey = torch.tensor([0.0, eps], dtype=torch.float64)
    for _ in range(iterations):
        res = distort_points(x, d) - q
        jx = (distort_points(x + ex, d) - distort_points(x - ex, d)) / (2 * eps)  # d/dx
        jy = (distort_points(x + ey, d) - distort_points(x - ey, d)) / (2 * eps)  # d/dy
        a, c = jx[..., 0], jx[..., 1]
        b, e = jy[..., 0], jy[..., 1]
        det = a * e - b * c
        det = torch.where(det.abs() > 1e-12, det, torch.full_like(det, 1e-12))
        step_x = (e * res[..., 0] - b * res[..., 1]) / det
        step_y = (-c * res[..., 0] + a * res[..., 1]) / det
        x = x - torch.stack([step_x, step_y], dim=-1)
        if float(res.abs().max()) < 1e-13:
            break
    return x.to(dtype)


def _normalised(camera: Camera, uv: Tensor) -> Tensor:
    K = camera.K.double()
    y = (uv[..., 1] - K[1, 2]) / K[1, 1]
    x = (uv[..., 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return torch.stack([x, y], dim=-1)


def _pixels(camera: Camera, xy: Tensor) -> Tensor:
    K = camera.K.to(xy)
    u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
    v = K[1, 1] * xy[..., 1] + K[1, 2]
    return torch.stack([u, v], dim=-1)


def undistorted_camera(camera: Camera, d: Distortion, samples: int = 256) -> Camera:
    """The pinhole camera (same pose and pixel size) that :func:`undistort_image` renders into.

    Its view is the largest one with ``camera``'s pixel aspect that fits inside the rectangle
    the undistorted image border encloses (sampled at ``samples`` points per edge), centred in
    that rectangle: every output pixel then maps inside the input image.

    Raises:
        ValueError: the distortion folds the image border over (no valid area is left).
    """
    if d.is_identity:
        return camera
    W, H = camera.width, camera.height
    t = torch.linspace(0.0, 1.0, samples, dtype=torch.float64)

    def edge(u: Tensor, v: Tensor) -> Tensor:
        return undistort_points(_normalised(camera, torch.stack([u, v], dim=-1)), d)

    left = edge(torch.zeros_like(t), t * H)
    right = edge(torch.full_like(t, float(W)), t * H)
    top = edge(t * W, torch.zeros_like(t))
    bottom = edge(t * W, torch.full_like(t, float(H)))
    x0, x1 = float(left[:, 0].max()), float(right[:, 0].min())
    y0, y1 = float(top[:, 1].max()), float(bottom[:, 1].min())
    if not (x1 > x0 and y1 > y0) or not all(map(math.isfinite, (x0, x1, y0, y1))):
        raise ValueError(
            f"the distortion {d} leaves no valid image area for a {W}x{H} camera; check the "
            "coefficients (and that they belong to this image size)"
        )
    # zoom so that both W/fx' <= x1-x0 and H/fy' <= y1-y0, keeping fx'/fy' = fx/fy
    zoom = max(W / (camera.fx * (x1 - x0)), H / (camera.fy * (y1 - y0)))
    fx, fy = zoom * camera.fx, zoom * camera.fy
    cx = W / 2 - fx * 0.5 * (x0 + x1)
    cy = H / 2 - fy * 0.5 * (y0 + y1)
    return Camera.from_intrinsics(fx, fy, cx, cy, W, H, camera.world_to_cam)


def undistort_image(
    image: Tensor, camera: Camera, d: Distortion, new_camera: Camera | None = None
) -> Tensor:
    """Resample ``image [C,H,W]`` (taken by ``camera`` with lens ``d``) onto the pinhole
    ``new_camera`` (default :func:`undistorted_camera`), bilinearly; returns ``[C,H',W']``.

    Each output pixel centre is cast through ``new_camera``, distorted with ``d`` and looked up
    in the input (pixel centres at +0.5, ``grid_sample`` with ``align_corners=False``); lookups
    that fall just outside the input take its border pixel.
    """
    if new_camera is None:
        new_camera = undistorted_camera(camera, d)
    if image.ndim != 3 or (image.shape[2], image.shape[1]) != (camera.width, camera.height):
        raise ValueError(
            f"undistort_image: image must be [C,{camera.height},{camera.width}] for this camera, "
            f"got {list(image.shape)}"
        )
    uv = new_camera.pixel_centers(torch.float64)  # [H',W',2]
    src = _pixels(camera, distort_points(_normalised(new_camera, uv), d))
    grid = torch.stack(
        [2 * src[..., 0] / camera.width - 1, 2 * src[..., 1] / camera.height - 1], dim=-1
    )
    out = F.grid_sample(
        image[None].float(),
        grid[None].to(torch.float32),
        mode="bilinear",
        padding_mode="border",
        align_corners=False,
    )
    return out[0]


def undistort_view(image: Tensor, camera: Camera, d: Distortion | None) -> tuple[Tensor, Camera]:
    """``image`` and ``camera`` unchanged without distortion, else undistorted (see above)."""
    if d is None or d.is_identity:
        return image, camera
    new = undistorted_camera(camera, d)
    return undistort_image(image, camera, d, new), new
