"""The one camera convention every part of ProSplat speaks.

A :class:`Camera` is a pinhole with OpenCV axes (x right, y down, z forward), intrinsics ``K``
in pixels and a 4x4 world-to-camera matrix. Pixel (col, row) has its centre at
(col + 0.5, row + 0.5), so a centred principal point is (W/2, H/2), which is how Blender
renders. Conversions from Blender, nerfstudio/instant-ngp ``transforms.json`` and COLMAP live
in :mod:`prosplat.convert` (``camera_from_blender`` / ``blender_from_camera``); everything
downstream only ever sees this class. This module imports nothing else of ProSplat, so the
converters can import it without a cycle.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor


def _as_matrix(value, shape: tuple[int, int], name: str) -> Tensor:
    t = torch.as_tensor(value)
    if not t.is_floating_point():
        t = t.to(torch.float64)
    if tuple(t.shape) != shape:
        raise ValueError(f"Camera.{name} must have shape {shape}, got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"Camera.{name} contains NaN or Inf: {t.tolist()}")
    return t


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
        K: [3, 3] intrinsics in pixels, ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
        world_to_cam: [4, 4] rigid transform from world to OpenCV camera coordinates.
        width, height: image size in pixels.
    """

    K: Tensor
    world_to_cam: Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        K = _as_matrix(self.K, (3, 3), "K")
        w2c = _as_matrix(self.world_to_cam, (4, 4), "world_to_cam").to(K.dtype)
        if int(self.width) != self.width or int(self.height) != self.height:
            raise ValueError(f"Camera size must be integers, got {self.width}x{self.height}")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"Camera size must be at least 1x1, got {self.width}x{self.height}")
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(
                f"Camera.K focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}"
            )
        if not torch.allclose(K[2], K.new_tensor([0.0, 0.0, 1.0])) or K[1, 0] != 0:
            raise ValueError(
                f"Camera.K must be upper triangular with last row [0, 0, 1], got {K.tolist()}"
            )
        if not torch.allclose(w2c[3], w2c.new_tensor([0.0, 0.0, 0.0, 1.0])):
            raise ValueError(
                f"Camera.world_to_cam last row must be [0, 0, 0, 1], got {w2c[3].tolist()}"
            )
        R = w2c[:3, :3].double()
        eye = torch.eye(3, dtype=R.dtype, device=R.device)
        if not torch.allclose(R @ R.T, eye, atol=1e-4) or torch.det(R) < 0:
            raise ValueError(
                "Camera.world_to_cam rotation must be orthonormal with det +1 (no scale or mirror); "
                "normalise the camera's matrix or remove object scale"
            )
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "world_to_cam", w2c)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_intrinsics(
        cls,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        width: int,
        height: int,
        world_to_cam: Tensor | None = None,
    ) -> Camera:
        K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float64)
        w2c = torch.eye(4, dtype=torch.float64) if world_to_cam is None else world_to_cam
        return cls(K, w2c, width, height)

    @classmethod
    def look_at(
        cls,
        eye: Sequence[float] | Tensor,
        target: Sequence[float] | Tensor,
        up: Sequence[float] | Tensor,
        fx: float,
        width: int,
        height: int,
        fy: float | None = None,
    ) -> Camera:
        """A camera at ``eye`` looking at ``target`` with image-up roughly along ``up``."""
        eye_t = torch.as_tensor(eye, dtype=torch.float64)
        z = torch.as_tensor(target, dtype=torch.float64) - eye_t
        if z.norm() == 0:
            raise ValueError("Camera.look_at: eye and target coincide")
        z = z / z.norm()
        up_t = torch.as_tensor(up, dtype=torch.float64)
        x = torch.linalg.cross(-up_t, z)  # OpenCV: y points down (−up), and x = y × z
        if x.norm() < 1e-12:
            raise ValueError(
                "Camera.look_at: up is parallel to the viewing direction; pick another up"
            )
        x = x / x.norm()
        y = torch.linalg.cross(z, x)
        R = torch.stack([x, y, z])  # rows: camera axes in world coordinates
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ eye_t
        return cls.from_intrinsics(
            fx, fy if fy is not None else fx, width / 2, height / 2, width, height, w2c
        )

    # ---- properties ---------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def R(self) -> Tensor:
        """[3, 3] world-to-camera rotation."""
        return self.world_to_cam[:3, :3]

    @property
    def t(self) -> Tensor:
        """[3] world-to-camera translation."""
        return self.world_to_cam[:3, 3]

    @property
    def cam_to_world(self) -> Tensor:
        """[4, 4] camera-to-world (OpenCV axes)."""
        c2w = torch.eye(4, dtype=self.world_to_cam.dtype, device=self.world_to_cam.device)
        c2w[:3, :3] = self.R.T
        c2w[:3, 3] = -self.R.T @ self.t
        return c2w

    @property
    def center(self) -> Tensor:
        """[3] camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> Tensor:
        """[3] unit viewing direction (the optical axis, +z) in world coordinates."""
        return self.R[2]

    @property
    def device(self) -> torch.device:
        return self.K.device

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> Camera:
        return Camera(
            self.K.to(device=device, dtype=dtype),
            self.world_to_cam.to(device=device, dtype=dtype),
            self.width,
            self.height,
        )

    # ---- geometry -----------------------------------------------------------------------
    def world_to_camera(self, points: Tensor) -> Tensor:
        """[..., 3] world points -> [..., 3] camera-space points (OpenCV axes)."""
        R = self.R.to(points)
        return points @ R.T + self.t.to(points)

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Project world points.

        Args:
            points: [..., 3] world coordinates.
        Returns:
            uv: [..., 2] continuous pixel coordinates (pixel (c, r) spans [c, c+1) x [r, r+1)).
            depth: [...] z along the optical axis; points with depth <= 0 get non-finite-free
                but meaningless uv (divided by a clamped depth), so mask them with ``depth > 0``.
        """
        pc = self.world_to_camera(points)
        z = pc[..., 2]
        z_safe = torch.where(z.abs() > 1e-12, z, torch.full_like(z, 1e-12))
        K = self.K.to(points)
        u = K[0, 0] * pc[..., 0] / z_safe + K[0, 1] * pc[..., 1] / z_safe + K[0, 2]
        v = K[1, 1] * pc[..., 1] / z_safe + K[1, 2]
        return torch.stack([u, v], dim=-1), z

    def nearest_pixels(self, points: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """The pixel each world point falls in, for depth-map lookups.

        Args:
            points: [M, 3] world coordinates.
        Returns:
            col, row: [M] long, clamped into the image so they can always index a map;
            depth: [M] z along the optical axis;
            inside: [M] bool, in front of the camera and within the image.
        """
        uv, z = self.project(points)
        col = torch.floor(uv[:, 0]).long()
        row = torch.floor(uv[:, 1]).long()
        inside = (z > 0) & (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return col.clamp(0, self.width - 1), row.clamp(0, self.height - 1), z, inside

    def unproject(self, uv: Tensor, depth: Tensor) -> Tensor:
        """Lift pixels to world points.

        Args:
            uv: [..., 2] pixel coordinates (centres at +0.5).
            depth: [...] z along the optical axis (not distance along the ray).
        Returns:
            [..., 3] world coordinates.
        """
        K = self.K.to(uv)
        y = (uv[..., 1] - K[1, 2]) / K[1, 1]
        x = (uv[..., 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        pc = torch.stack([x * depth, y * depth, depth], dim=-1)
        R = self.R.to(uv)
        return (pc - self.t.to(uv)) @ R  # R^T (p - t), row-vector form

    def pixel_centers(self, dtype: torch.dtype = torch.float32) -> Tensor:
        """[H, W, 2] (u, v) coordinates of every pixel centre."""
        v, u = torch.meshgrid(
            torch.arange(self.height, dtype=dtype, device=self.device) + 0.5,
            torch.arange(self.width, dtype=dtype, device=self.device) + 0.5,
            indexing="ij",
        )
        return torch.stack([u, v], dim=-1)

    def ray_directions(self, dtype: torch.dtype = torch.float32) -> Tensor:
        """[H, W, 3] world-space unit ray directions through every pixel centre."""
        uv = self.pixel_centers(dtype)
        pts = self.unproject(uv, torch.ones(uv.shape[:-1], dtype=dtype, device=self.device))
        d = pts - self.center.to(pts)
        return d / d.norm(dim=-1, keepdim=True)

    def resized(self, width: int, height: int) -> Camera:
        """The same camera at another image size (intrinsics scaled per axis)."""
        K = self.K.clone()
        K[0] *= width / self.width
        K[1] *= height / self.height
        K[2] = K.new_tensor([0.0, 0.0, 1.0])
        return Camera(K, self.world_to_cam, width, height)


@dataclass(frozen=True)
class CameraBatch:
    """Cameras stacked into tensors: ``K [B,3,3]``, ``world_to_cam [B,4,4]``, ``sizes [B,2]`` (W, H)."""

    K: Tensor
    world_to_cam: Tensor
    sizes: Tensor

    def __len__(self) -> int:
        return self.K.shape[0]

    @property
    def centers(self) -> Tensor:
        """[B, 3] camera centres in world coordinates."""
        R = self.world_to_cam[:, :3, :3]
        t = self.world_to_cam[:, :3, 3]
        return -(R.transpose(1, 2) @ t[..., None])[..., 0]

    @property
    def forwards(self) -> Tensor:
        """[B, 3] unit viewing directions in world coordinates."""
        return self.world_to_cam[:, 2, :3]

    def __getitem__(self, i: int) -> Camera:
        w, h = self.sizes[i].tolist()
        return Camera(self.K[i], self.world_to_cam[i], int(w), int(h))


def stack_cameras(cameras: Sequence[Camera]) -> CameraBatch:
    """Stack a list of cameras into a :class:`CameraBatch` (common dtype/device of the first)."""
    if len(cameras) == 0:
        raise ValueError("stack_cameras needs at least one camera")
    dtype, device = cameras[0].K.dtype, cameras[0].K.device
    K = torch.stack([c.K.to(device=device, dtype=dtype) for c in cameras])
    w2c = torch.stack([c.world_to_cam.to(device=device, dtype=dtype) for c in cameras])
    sizes = torch.tensor([[c.width, c.height] for c in cameras], dtype=torch.long, device=device)
    return CameraBatch(K, w2c, sizes)
