"""Blender camera <-> :class:`~prosplat.core.camera.Camera`, as pure math (no ``bpy``).

Blender describes a perspective camera by its object's world matrix (the camera looks down
its local −Z with +Y up, the OpenGL axes) and by lens, sensor size, sensor fit and lens shift;
the image size comes from the scene. This module reproduces the projection Blender renders
with (``BKE_camera_params_compute_viewplane``, which Cycles and EEVEE share):

* The *fitted* side of the frame is the width for sensor fit HORIZONTAL, the height for
  VERTICAL, and for AUTO whichever side is longer (width wins a tie). The sensor size that
  spans it is ``sensor_height`` for VERTICAL and ``sensor_width`` otherwise — so AUTO always
  maps ``sensor_width`` onto the longer side, portrait or landscape.
* ``viewfac`` is the fitted side in pixels, measured in units of a pixel's width (so the
  height counts ``height * pixel_aspect_y / pixel_aspect_x``). Then
  ``fx = lens / sensor * viewfac`` and ``fy = fx * pixel_aspect_x / pixel_aspect_y``.
* Lens shift is a fraction of that same fitted side, for both x and y: a shift of 1 moves
  the frame by one full fitted side. Positive shift moves the frame right/up, so the optical
  axis lands left of/below the image centre: ``cx = W/2 - shift_x * viewfac`` and
  ``cy = H/2 + shift_y * viewfac * pixel_aspect_x / pixel_aspect_y``.
* The frame spans exactly W x H pixels whose centres Cycles samples at +0.5, the same
  convention as :class:`Camera`, so no half-pixel offset appears anywhere.

The object matrix may carry scale (Blender draws a bigger camera); it does not change the
image, so it is removed by normalising the rotation columns, as ``world_to_camera_view``
does. Negative scale (a mirror) or zero scale cannot be a camera and is rejected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from prosplat.core.camera import Camera

__all__ = [
    "OPENGL_TO_OPENCV",
    "SENSOR_FITS",
    "BlenderCameraParams",
    "blender_from_camera",
    "blender_render_size",
    "blender_to_opencv_c2w",
    "camera_from_blender",
    "opencv_to_blender_c2w",
]

#: [4, 4] camera-axis flip between OpenGL/Blender cameras (x right, y up, look down −z) and
#: OpenCV cameras (x right, y down, look down +z). Right-multiply a camera-to-world matrix by
#: it to switch conventions; it is its own inverse, so the same matrix serves both directions.
#: nerfstudio/instant-ngp ``transform_matrix`` uses the same OpenGL axes. Treat as read-only.
OPENGL_TO_OPENCV: Tensor = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")

# How far normalised rotation columns may be from orthonormal before we call it shear. Blender
# stores matrices in float32 (~1e-7); a sheared parent chain is off by far more.
_SHEAR_TOL = 1e-5


def _matrix64(value, name: str) -> Tensor:
    """[4, 4] float64 copy of a tensor, array, nested list or ``mathutils.Matrix`` (rows)."""
    if isinstance(value, Tensor):
        m = value.detach().to(device="cpu", dtype=torch.float64)
    else:
        m = torch.as_tensor(np.asarray(value, dtype=np.float64))
    if tuple(m.shape) != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix, got shape {tuple(m.shape)}")
    if not torch.isfinite(m).all():
        raise ValueError(f"{name} contains NaN or Inf: {m.tolist()}")
    if not torch.allclose(m[3], m.new_tensor([0.0, 0.0, 0.0, 1.0]), atol=1e-6):
        raise ValueError(f"{name} must be affine with last row [0, 0, 0, 1], got {m[3].tolist()}")
    return m


def _positive(value: float, name: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"Blender camera {name} must be a positive finite number, got {value!r}")
    return v


def _finite(value: float, name: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"Blender camera {name} must be finite, got {value!r}")
    return v


def _size(value: int, name: str) -> int:
    if int(value) != value or value < 1:
        raise ValueError(f"Blender image {name} must be a positive integer, got {value!r}")
    return int(value)


def blender_to_opencv_c2w(matrix_world) -> Tensor:
    """Blender camera world matrix [4, 4] -> OpenCV camera-to-world [4, 4] (float64).

    Object scale is removed by normalising each rotation column (Blender's
    ``matrix_world.normalized()``), then the camera axes are flipped with
    :data:`OPENGL_TO_OPENCV`.

    Raises:
        ValueError: non-finite, non-affine, zero-scale, mirrored (negative scale) or sheared
            matrices, which no camera can have.
    """
    m = _matrix64(matrix_world, "matrix_world")
    norms = m[:3, :3].norm(dim=0)  # [3] per-axis object scale
    if not (norms > 1e-12).all():
        raise ValueError(
            f"matrix_world has a zero-scale axis (column norms {norms.tolist()}); "
            "give the camera object a non-zero scale"
        )
    R = m[:3, :3] / norms  # [3, 3] columns: camera x, y, z axes in world
    if torch.det(R) < 0:
        raise ValueError(
            "matrix_world is mirrored (negative scale on the camera or a parent); "
            "use positive scale so the camera keeps a right-handed frame"
        )
    if (R.T @ R - torch.eye(3, dtype=R.dtype)).abs().max() > _SHEAR_TOL:
        raise ValueError(
            "matrix_world is sheared (non-uniform scale on a rotated parent); "
            "clear the parent's scale or apply it before converting the camera"
        )
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3] = R
    c2w[:3, 3] = m[:3, 3]
    return c2w @ OPENGL_TO_OPENCV


def opencv_to_blender_c2w(c2w) -> Tensor:
    """OpenCV camera-to-world [4, 4] -> Blender camera world matrix [4, 4] (no scale)."""
    return _matrix64(c2w, "c2w") @ OPENGL_TO_OPENCV


def blender_render_size(resolution_x: int, resolution_y: int, percentage: int) -> tuple[int, int]:
    """The pixel size Blender renders: ``resolution * percentage // 100`` (truncated).

    This is ``BKE_render_resolution``; pass its result as ``width, height`` to
    :func:`camera_from_blender`. Note the truncation can change the aspect slightly (e.g.
    1001x1899 at 37% is 370x702), and Blender's projection follows the truncated size.
    """
    rx = _size(resolution_x, "resolution_x")
    ry = _size(resolution_y, "resolution_y")
    pct = _size(percentage, "resolution_percentage")
    return rx * pct // 100, ry * pct // 100


def _fitted_side(
    width: int, height: int, sensor_fit: str, pixel_aspect_x: float, pixel_aspect_y: float
) -> float:
    """Pixels (in pixel-width units) across the side the sensor spans: Blender's ``viewfac``."""
    ycor = pixel_aspect_y / pixel_aspect_x
    if sensor_fit == "HORIZONTAL":
        horizontal = True
    elif sensor_fit == "VERTICAL":
        horizontal = False
    else:  # AUTO: the longer side of the displayed frame, width on a tie (BKE_camera_sensor_fit)
        horizontal = width * pixel_aspect_x >= height * pixel_aspect_y
    return float(width) if horizontal else height * ycor


def _check_fit(sensor_fit: str) -> str:
    fit = str(sensor_fit).upper()
    if fit not in SENSOR_FITS:
        raise ValueError(f"sensor_fit must be one of {SENSOR_FITS}, got {sensor_fit!r}")
    return fit


def camera_from_blender(
    matrix_world,
    lens: float,
    sensor_width: float,
    sensor_height: float,
    sensor_fit: str,
    shift_x: float,
    shift_y: float,
    width: int,
    height: int,
    *,
    pixel_aspect_x: float = 1.0,
    pixel_aspect_y: float = 1.0,
) -> Camera:
    """The :class:`Camera` that projects exactly as a Blender perspective camera renders.

    Args:
        matrix_world: [4, 4] the camera object's world matrix (may include positive scale).
        lens: focal length in mm (``camera.data.lens``).
        sensor_width, sensor_height: sensor size in mm.
        sensor_fit: ``'AUTO'``, ``'HORIZONTAL'`` or ``'VERTICAL'``.
        shift_x, shift_y: lens shift, in units of the fitted side (see module docstring).
        width, height: the final rendered pixel size, after the resolution percentage
            (:func:`blender_render_size`).
        pixel_aspect_x, pixel_aspect_y: ``scene.render.pixel_aspect_x/y``; non-square pixels
            give ``fx != fy``.

    Returns:
        A float64 camera with OpenCV axes; centred principal point is (W/2, H/2).
    """
    fit = _check_fit(sensor_fit)
    lens = _positive(lens, "lens")
    sensor_width = _positive(sensor_width, "sensor_width")
    sensor_height = _positive(sensor_height, "sensor_height")
    shift_x = _finite(shift_x, "shift_x")
    shift_y = _finite(shift_y, "shift_y")
    width = _size(width, "width")
    height = _size(height, "height")
    ax = _positive(pixel_aspect_x, "pixel_aspect_x")
    ay = _positive(pixel_aspect_y, "pixel_aspect_y")

    sensor = sensor_height if fit == "VERTICAL" else sensor_width
    viewfac = _fitted_side(width, height, fit, ax, ay)
    ycor = ay / ax
    fx = lens / sensor * viewfac
    fy = fx / ycor
    cx = width / 2 - shift_x * viewfac
    cy = height / 2 + shift_y * viewfac / ycor

    c2w = blender_to_opencv_c2w(matrix_world)  # [4, 4] OpenCV camera-to-world
    # The true inverse, not the transpose: Blender stores float32 matrices whose normalised
    # rotation is orthonormal only to ~4e-8, and renders with the inverse of exactly that
    # matrix; at f = 3000 px the transpose would be off by ~1e-4 px.
    w2c = torch.linalg.inv(c2w)  # [4, 4]
    w2c[3] = w2c.new_tensor([0.0, 0.0, 0.0, 1.0])
    return Camera.from_intrinsics(fx, fy, cx, cy, width, height, w2c)


@dataclass(frozen=True)
class BlenderCameraParams:
    """Everything needed to place a Blender camera that renders like a :class:`Camera`.

    Set ``obj.matrix_world``, ``obj.data.lens/sensor_*/shift_*``, and
    ``scene.render.resolution_x/y = width/height`` with ``resolution_percentage = 100`` and
    ``pixel_aspect_x/y``. ``sensor_fit`` is Blender's default ``'AUTO'``; ``sensor_height``
    does not affect AUTO and is set so the sensor outline has the frame's aspect.

    Attributes:
        matrix_world: [4, 4] float64 camera object world matrix (no scale, Blender axes).
    """

    matrix_world: Tensor
    lens: float
    sensor_width: float
    sensor_height: float
    sensor_fit: str
    shift_x: float
    shift_y: float
    width: int
    height: int
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0

    def to_camera(self) -> Camera:
        """The :class:`Camera` these settings render (inverse of :func:`blender_from_camera`)."""
        return camera_from_blender(
            self.matrix_world, self.lens, self.sensor_width, self.sensor_height,
            self.sensor_fit, self.shift_x, self.shift_y, self.width, self.height,
            pixel_aspect_x=self.pixel_aspect_x, pixel_aspect_y=self.pixel_aspect_y,
        )  # fmt: skip


def blender_from_camera(camera: Camera, sensor_width: float = 36.0) -> BlenderCameraParams:
    """Blender settings that render exactly the view of ``camera`` (inverse of
    :func:`camera_from_blender`, exact to float64 round-off).

    ``fx != fy`` becomes a non-square pixel aspect (Blender only allows aspects >= 1, so the
    smaller of the two is 1). Skew has no Blender equivalent and raises ``ValueError``.
    """
    sensor_width = _positive(sensor_width, "sensor_width")
    K = camera.K.detach().to(device="cpu", dtype=torch.float64)
    if float(K[0, 1]) != 0.0:
        raise ValueError(
            f"Blender cameras have no skew, but this camera has K[0, 1] = {float(K[0, 1])}; "
            "resample the image to a skew-free camera first"
        )
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    W, H = camera.width, camera.height
    ycor = fx / fy  # = pixel_aspect_y / pixel_aspect_x
    ax, ay = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    viewfac = _fitted_side(W, H, "AUTO", ax, ay)
    lens = fx * sensor_width / viewfac
    shift_x = (W / 2 - cx) / viewfac
    shift_y = (cy - H / 2) * ycor / viewfac
    long_side, short_side = max(W, H * ycor), min(W, H * ycor)
    sensor_height = sensor_width * short_side / long_side

    w2c = camera.world_to_cam.detach().to(device="cpu", dtype=torch.float64)
    c2w = torch.linalg.inv(w2c)  # [4, 4] OpenCV camera-to-world (inverse, as above)
    c2w[3] = c2w.new_tensor([0.0, 0.0, 0.0, 1.0])
    return BlenderCameraParams(
        matrix_world=opencv_to_blender_c2w(c2w),
        lens=lens,
        sensor_width=sensor_width,
        sensor_height=sensor_height,
        sensor_fit="AUTO",
        shift_x=shift_x,
        shift_y=shift_y,
        width=W,
        height=H,
        pixel_aspect_x=ax,
        pixel_aspect_y=ay,
    )
