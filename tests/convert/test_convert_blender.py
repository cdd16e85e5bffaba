"""Blender camera conversion: hand-derived references, exact round trips, and Blender itself.

The ``blender``-marked tests build cameras with ``bpy`` and compare our projection against
``bpy_extras.object_utils.world_to_camera_view`` and against the projection matrix Blender's
renderer uses (``Object.calc_matrix_camera``), covering every sensor fit, portrait and
landscape, lens shift, resolution percentage, pixel aspect and a rotated, scaled camera.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prosplat import Camera
from prosplat.convert.blender import (
    OPENGL_TO_OPENCV,
    BlenderCameraParams,
    blender_from_camera,
    blender_render_size,
    blender_to_opencv_c2w,
    camera_from_blender,
)

F64 = torch.float64


def _trs(loc, euler_xyz, scale) -> torch.Tensor:
    """[4, 4] Blender-style matrix: translation @ rotation (XYZ euler) @ scale."""
    rx, ry, rz = euler_xyz
    cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                              math.cos(rz), math.sin(rz))  # fmt: skip
    Rx = torch.tensor([[1, 0, 0], [0, cx, -sx], [0, sx, cx]], dtype=F64)
    Ry = torch.tensor([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]], dtype=F64)
    Rz = torch.tensor([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]], dtype=F64)
    m = torch.eye(4, dtype=F64)
    m[:3, :3] = Rz @ Ry @ Rx @ torch.diag(torch.tensor(scale, dtype=F64))
    m[:3, 3] = torch.tensor(loc, dtype=F64)
    return m


# ---- hand-derived references ------------------------------------------------------------


def test_identity_camera_looks_down_minus_z() -> None:
    cam = camera_from_blender(torch.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 1920, 1080)
    torch.testing.assert_close(cam.forward, torch.tensor([0.0, 0.0, -1.0], dtype=F64))
    # 50 mm on a 36 mm sensor spanning 1920 px: f = 50/36*1920 px, centred principal point.
    f = 50.0 / 36.0 * 1920
    torch.testing.assert_close(
        cam.K, torch.tensor([[f, 0, 960.0], [0, f, 540.0], [0, 0, 1]], dtype=F64)
    )
    # World +Y is image up, world +X image right; depth is distance along −Z.
    uv, d = cam.project(torch.tensor([[0.0, 0.0, -10.0], [1.0, 2.0, -10.0]], dtype=F64))
    torch.testing.assert_close(uv[0], torch.tensor([960.0, 540.0], dtype=F64))
    torch.testing.assert_close(uv[1], torch.tensor([960.0 + f / 10, 540.0 - 2 * f / 10], dtype=F64))
    torch.testing.assert_close(d, torch.tensor([10.0, 10.0], dtype=F64))


@pytest.mark.parametrize(
    ("fit", "w", "h", "fx", "fy"),
    [
        # AUTO: sensor_width spans the longer side, portrait or landscape.
        ("AUTO", 1920, 1080, 50 / 36 * 1920, 50 / 36 * 1920),
        ("AUTO", 1080, 1920, 50 / 36 * 1920, 50 / 36 * 1920),
        # HORIZONTAL: sensor_width spans the width even in portrait.
        ("HORIZONTAL", 1080, 1920, 50 / 36 * 1080, 50 / 36 * 1080),
        # VERTICAL: sensor_height spans the height.
        ("VERTICAL", 1920, 1080, 50 / 24 * 1080, 50 / 24 * 1080),
        ("VERTICAL", 1080, 1920, 50 / 24 * 1920, 50 / 24 * 1920),
    ],
)
def test_sensor_fit_focal(fit: str, w: int, h: int, fx: float, fy: float) -> None:
    cam = camera_from_blender(torch.eye(4), 50.0, 36.0, 24.0, fit, 0.0, 0.0, w, h)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((fx, fy, w / 2, h / 2), rel=1e-12)


@pytest.mark.parametrize(
    ("fit", "w", "h", "cx", "cy"),
    [
        # Shift is a fraction of the fitted side for both axes; +x moves the frame right (the
        # axis lands left of centre), +y moves it up (the axis lands below centre).
        ("AUTO", 1920, 1080, 960 - 0.1 * 1920, 540 + 0.2 * 1920),
        ("AUTO", 1080, 1920, 540 - 0.1 * 1920, 960 + 0.2 * 1920),
        ("HORIZONTAL", 1080, 1920, 540 - 0.1 * 1080, 960 + 0.2 * 1080),
        ("VERTICAL", 1920, 1080, 960 - 0.1 * 1080, 540 + 0.2 * 1080),
    ],
)
def test_shift_principal_point(fit: str, w: int, h: int, cx: float, cy: float) -> None:
    cam = camera_from_blender(torch.eye(4), 50.0, 36.0, 24.0, fit, 0.1, 0.2, w, h)
    assert (cam.cx, cam.cy) == pytest.approx((cx, cy), rel=1e-12)


def test_pixel_aspect_gives_non_square_focal() -> None:
    # Pixels twice as tall as wide: the height counts double when fitting, and fy = fx / 2.
    cam = camera_from_blender(
        torch.eye(4), 50.0, 36.0, 24.0, "AUTO", 0.1, 0.1, 500, 450,
        pixel_aspect_x=1.0, pixel_aspect_y=2.0,
    )  # fmt: skip
    viewfac = 450 * 2.0  # 450 px of height * 2 > 500 px of width: vertical fit
    assert cam.fx == pytest.approx(50 / 36 * viewfac)
    assert cam.fy == pytest.approx(50 / 36 * viewfac / 2)
    assert (cam.cx, cam.cy) == pytest.approx((250 - 0.1 * viewfac, 225 + 0.1 * viewfac / 2))


def test_object_scale_is_ignored() -> None:
    args = (40.0, 30.0, 20.0, "AUTO", 0.05, -0.1, 640, 480)
    plain = camera_from_blender(_trs((1, 2, 3), (0.3, -0.4, 1.2), (1, 1, 1)), *args)
    scaled = camera_from_blender(_trs((1, 2, 3), (0.3, -0.4, 1.2), (2.0, 0.5, 3.0)), *args)
    torch.testing.assert_close(scaled.world_to_cam, plain.world_to_cam, rtol=0, atol=1e-12)
    torch.testing.assert_close(plain.center, torch.tensor([1.0, 2.0, 3.0], dtype=F64))


def test_axis_flip_is_shared_and_self_inverse() -> None:
    torch.testing.assert_close(OPENGL_TO_OPENCV @ OPENGL_TO_OPENCV, torch.eye(4, dtype=F64))
    m = _trs((0.5, -1, 2), (1.0, 0.2, -0.3), (1, 1, 1))
    torch.testing.assert_close(blender_to_opencv_c2w(m), m @ OPENGL_TO_OPENCV)


@pytest.mark.parametrize(
    ("matrix", "match"),
    [
        (torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0])), "mirrored"),
        (torch.diag(torch.tensor([1.0, 0.0, 1.0, 1.0])), "zero-scale"),
        (torch.full((4, 4), float("nan")), "NaN"),
        (torch.eye(3), "4x4"),
        # A sheared matrix: what a non-uniform parent scale does to a rotated child.
        (torch.diag(torch.tensor([1.0, 3.0, 1.0, 1.0], dtype=F64)) @ _trs((0, 0, 0), (0, 0, 0.7), (1, 1, 1)),
         "sheared"),
    ],
)  # fmt: skip
def test_bad_matrix_world(matrix: torch.Tensor, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        camera_from_blender(matrix, 50.0, 36.0, 24.0, "AUTO", 0.0, 0.0, 64, 48)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sensor_fit": "DIAGONAL"}, "sensor_fit"),
        ({"lens": 0.0}, "lens"),
        ({"shift_x": float("nan")}, "shift_x"),
        ({"width": 0}, "width"),
        ({"pixel_aspect_x": -1.0}, "pixel_aspect_x"),
    ],
)
def test_bad_parameters(kwargs: dict, match: str) -> None:
    args = dict(
        matrix_world=torch.eye(4), lens=50.0, sensor_width=36.0, sensor_height=24.0,
        sensor_fit="AUTO", shift_x=0.0, shift_y=0.0, width=64, height=48,
    )  # fmt: skip
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        camera_from_blender(**args)


def test_render_size_truncates_like_blender() -> None:
    assert blender_render_size(1920, 1080, 50) == (960, 540)
    assert blender_render_size(1001, 1899, 37) == (370, 702)


# ---- exact round trips ------------------------------------------------------------------


def _cameras() -> list[Camera]:
    base = Camera.look_at([3.0, -4.0, 2.0], [0.2, 0.1, 0.5], [0, 0, 1], 1000.0, 1920, 1080)
    w2c = base.world_to_cam
    return [
        base,
        Camera.from_intrinsics(900.0, 900.0, 300.25, 700.5, 720, 1280, w2c),  # portrait, off-centre
        Camera.from_intrinsics(800.0, 400.0, 410.0, 290.0, 800, 600, w2c),  # fx > fy
        Camera.from_intrinsics(300.0, 750.0, 200.0, 100.0, 400, 300, w2c),  # fx < fy
        Camera.from_intrinsics(500.0, 500.0, 256.0, 256.0, 512, 512, w2c),  # square image
    ]


@pytest.mark.parametrize("index", range(5))
def test_round_trip_camera_blender_camera(index: int) -> None:
    cam = _cameras()[index]
    params = blender_from_camera(cam, sensor_width=36.0)
    assert isinstance(params, BlenderCameraParams)
    assert params.sensor_fit == "AUTO"
    assert min(params.pixel_aspect_x, params.pixel_aspect_y) == 1.0  # Blender needs >= 1
    back = params.to_camera()
    torch.testing.assert_close(back.K, cam.K, rtol=0, atol=1e-9)
    torch.testing.assert_close(back.world_to_cam, cam.world_to_cam, rtol=0, atol=1e-9)
    assert (back.width, back.height) == (cam.width, cam.height)


def test_centred_camera_has_no_shift() -> None:
    params = blender_from_camera(_cameras()[0])
    assert (params.shift_x, params.shift_y) == (0.0, 0.0)
    assert params.lens == pytest.approx(1000.0 * 36.0 / 1920)
    assert params.sensor_height == pytest.approx(36.0 * 1080 / 1920)


def test_skew_is_refused() -> None:
    K = torch.tensor([[100.0, 2.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]], dtype=F64)
    with pytest.raises(ValueError, match="skew"):
        blender_from_camera(Camera(K, torch.eye(4, dtype=F64), 100, 100))


# ---- against Blender itself ---------------------------------------------------------------

# (sensor_fit, resolution_x, resolution_y, percentage, shift_x, shift_y, pixel_aspect_x/_y)
BLENDER_CASES = [
    ("AUTO", 1920, 1080, 100, 0.1, -0.2, 1.0, 1.0),
    ("AUTO", 1000, 1900, 37, -0.15, 0.05, 1.0, 1.0),  # portrait, 370x703
    ("AUTO", 1000, 900, 50, 0.05, 0.08, 1.0, 2.0),  # tall pixels turn AUTO vertical
    ("HORIZONTAL", 1200, 1600, 50, 0.2, 0.1, 1.0, 1.0),
    ("HORIZONTAL", 1600, 900, 37, 0.0, 0.3, 1.0, 1.0),  # 592x333
    ("VERTICAL", 1600, 1000, 50, 0.12, -0.07, 1.0, 1.0),
    ("VERTICAL", 1000, 1600, 100, -0.1, 0.2, 1.0, 1.0),
    ("VERTICAL", 800, 600, 100, 0.1, 0.1, 3.0, 2.0),
]


@pytest.fixture
def bpy_scene():
    """A fresh, empty Blender scene with one camera object in it."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    data = bpy.data.cameras.new("cam")
    obj = bpy.data.objects.new("cam", data)
    scene.collection.objects.link(obj)
    scene.camera = obj
    return scene, obj


def _set_blender_camera(scene, obj, matrix_world, lens, sw, sh, fit, sx, sy, rx, ry, pct, ax, ay):
    import bpy
    from mathutils import Matrix

    obj.matrix_world = Matrix(np.asarray(matrix_world, dtype=np.float64).tolist())
    data = obj.data
    data.type = "PERSP"
    data.lens, data.sensor_width, data.sensor_height, data.sensor_fit = lens, sw, sh, fit
    data.shift_x, data.shift_y = sx, sy
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = rx, ry, pct
    r.pixel_aspect_x, r.pixel_aspect_y = ax, ay
    # Evaluate now: Blender rebuilds matrix_world from the decomposed loc/rot/scale (changing
    # it by float32 round-off), and that evaluated matrix is the one it projects with.
    bpy.context.view_layer.update()


def _local_points(n: int, seed: int, spread: float) -> np.ndarray:
    """[n, 3] points in Blender camera-local coordinates (−Z ahead), ``|x|, |y| <= spread*z``."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.5, 30.0, n)
    xy = rng.uniform(-spread, spread, (n, 2)) * z[:, None]
    return np.column_stack([xy, -z])


def _normalized64(obj) -> np.ndarray:
    """[4, 4] the camera's matrix_world with scale removed in float64.

    ``Matrix.normalized()`` works in float32 and leaves the rotation orthonormal only to
    ~2e-7, which alone moves a pixel by up to ~1e-3 px at f = 3000 px; normalising in float64
    isolates the projection model from that round-off.
    """
    m = np.array(obj.matrix_world, dtype=np.float64)
    m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)
    return m


def _blender_uv(scene, obj, points: np.ndarray, W: int, H: int):
    """world_to_camera_view -> ([n, 2] pixels in our convention, [n] depth)."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    out = np.array([tuple(world_to_camera_view(scene, obj, Vector(p))) for p in points])
    return np.column_stack([out[:, 0] * W, (1.0 - out[:, 1]) * H]), out[:, 2]


def _render_matrix_uv(obj, points: np.ndarray, W: int, H: int, ax: float, ay: float):
    """Project with the renderer's own matrices (calc_matrix_camera at the final size)."""
    import bpy

    depsgraph = bpy.context.evaluated_depsgraph_get()
    P = np.array(obj.calc_matrix_camera(depsgraph, x=W, y=H, scale_x=ax, scale_y=ay))
    V = np.linalg.inv(_normalized64(obj))
    clip = np.column_stack([points, np.ones(len(points))]) @ (P @ V).T
    ndc = clip[:, :2] / clip[:, 3:]
    return np.column_stack([(ndc[:, 0] + 1) / 2 * W, (1 - ndc[:, 1]) / 2 * H])


def _world_points(obj, n: int = 64, seed: int = 0, spread: float = 0.45) -> np.ndarray:
    """[n, 3] world points in front of the camera; the default spread covers the frames of
    the cases below (tan of half the field of view is 0.25-0.36, plus shift)."""
    M = _normalized64(obj)
    return _local_points(n, seed, spread) @ M[:3, :3].T + M[:3, 3]


@pytest.mark.blender
@pytest.mark.parametrize("case", BLENDER_CASES, ids=lambda c: f"{c[0]}-{c[1]}x{c[2]}@{c[3]}")
def test_projection_matches_blender(bpy_scene, case) -> None:
    scene, obj = bpy_scene
    fit, rx, ry, pct, sx, sy, ax, ay = case
    matrix = _trs((1.5, -2.0, 0.7), (1.1, -0.4, 2.3), (2.0, 0.5, 1.5))  # rotated and scaled
    lens, sw, sh = 42.0, 30.0, 21.0
    _set_blender_camera(scene, obj, matrix, lens, sw, sh, fit, sx, sy, rx, ry, pct, ax, ay)
    W, H = blender_render_size(rx, ry, pct)
    # world_to_camera_view uses the un-percentaged aspect; these cases scale exactly.
    assert (rx * pct % 100, ry * pct % 100) == (0, 0)

    # Feed our conversion what Blender actually holds (float32 values, its matrix_world).
    data = obj.data
    cam = camera_from_blender(
        np.array(obj.matrix_world), data.lens, data.sensor_width, data.sensor_height,
        data.sensor_fit, data.shift_x, data.shift_y, W, H,
        pixel_aspect_x=scene.render.pixel_aspect_x, pixel_aspect_y=scene.render.pixel_aspect_y,
    )  # fmt: skip
    pts = _world_points(obj)
    uv, depth = cam.project(torch.as_tensor(pts, dtype=F64))
    ref_uv, ref_depth = _blender_uv(scene, obj, pts, W, H)
    err = np.abs(uv.numpy() - ref_uv).max()
    assert err < 1e-3, f"max projection error vs world_to_camera_view {err:.2e} px"
    np.testing.assert_allclose(depth.numpy(), ref_depth, rtol=1e-5, atol=1e-5)
    render_uv = _render_matrix_uv(obj, pts, W, H, ax, ay)
    err_render = np.abs(uv.numpy() - render_uv).max()
    assert err_render < 5e-4, f"max error vs calc_matrix_camera {err_render:.2e} px"


@pytest.mark.blender
def test_truncated_percentage_matches_render_matrix(bpy_scene) -> None:
    # 1001x1899 at 37% renders 370x702 (truncated), a slightly different aspect than the
    # resolution fields; the renderer follows the truncated size, and so do we.
    scene, obj = bpy_scene
    matrix = _trs((0.0, 3.0, 1.0), (0.2, 0.9, -1.3), (1.0, 1.0, 1.0))
    _set_blender_camera(scene, obj, matrix, 35.0, 36.0, 24.0, "AUTO", 0.07, -0.03,
                        1001, 1899, 37, 1.0, 1.0)  # fmt: skip
    W, H = blender_render_size(1001, 1899, 37)
    cam = camera_from_blender(
        np.array(obj.matrix_world), 35.0, 36.0, 24.0, "AUTO", 0.07, -0.03, W, H
    )
    pts = _world_points(obj, seed=1, spread=0.6)
    uv, _ = cam.project(torch.as_tensor(pts, dtype=F64))
    assert np.abs(uv.numpy() - _render_matrix_uv(obj, pts, W, H, 1.0, 1.0)).max() < 1e-3


@pytest.mark.blender
@pytest.mark.parametrize("index", range(5))
def test_blender_from_camera_renders_same_view(bpy_scene, index: int) -> None:
    scene, obj = bpy_scene
    cam = _cameras()[index]
    p = blender_from_camera(cam)
    _set_blender_camera(
        scene, obj, p.matrix_world, p.lens, p.sensor_width, p.sensor_height, p.sensor_fit,
        p.shift_x, p.shift_y, p.width, p.height, 100, p.pixel_aspect_x, p.pixel_aspect_y,
    )  # fmt: skip
    pts = _world_points(obj, seed=2, spread=0.8)
    uv, depth = cam.project(torch.as_tensor(pts, dtype=F64))
    ref_uv, ref_depth = _blender_uv(scene, obj, pts, cam.width, cam.height)
    assert np.abs(uv.numpy() - ref_uv).max() < 1e-3
    np.testing.assert_allclose(depth.numpy(), ref_depth, rtol=1e-5, atol=1e-5)
    render_uv = _render_matrix_uv(
        obj, pts, cam.width, cam.height, p.pixel_aspect_x, p.pixel_aspect_y
    )
    assert np.abs(uv.numpy() - render_uv).max() < 1e-3
