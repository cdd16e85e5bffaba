"""Blender 5.3's own Gaussian splats (issue 66): the add-on's clouds are ``GAUSSIAN_SPLAT``
point clouds in the layout Blender's own PLY importer writes, so they render as Blender's
import does, and a cloud Blender imported itself goes through Render View and Export PLY.

The reference is Blender's own importer (``bpy.ops.wm.ply_import``) on the same PLY. Skipped
on a Blender without native splats (before 5.3), where ``test_addon_splat_display.py`` covers
the mesh display.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, run_op  # noqa: E402
from factories import random_gaussians  # noqa: E402
from test_addon_splat_display import (  # noqa: E402
    RED_GREEN,
    SIZE,
    _assert_red_and_green,
    _camera,
    _render,
    _splats,
)

from addon.blender import api, native_splats, pointcloud  # noqa: E402
from addon.core import splat_math  # noqa: E402
from prosplat import read_ply, write_ply  # noqa: E402
from prosplat.convert.pointcloud import to_attributes  # noqa: E402
from prosplat.core.image_io import read_image  # noqa: E402

if not native_splats.supported():
    pytest.skip(f"Blender {bpy.app.version_string} has no native Gaussian splats (5.3+)",
                allow_module_level=True)  # fmt: skip


def _ours(path: Path):
    res, err = run_op(bpy.ops.prosplat.import_ply, filepath=str(path))
    assert res == {"FINISHED"}, err
    return bpy.context.scene.prosplat.gaussians


def _blenders(path: Path):
    """Blender's own File > Import > PLY (the new object is the active one)."""
    before = set(bpy.data.objects)
    bpy.ops.wm.ply_import(filepath=str(path))
    (obj,) = set(bpy.data.objects) - before
    return obj


def _attribute(obj, name: str) -> np.ndarray:
    attr = obj.data.attributes[name]
    width = {"FLOAT": 1, "FLOAT_VECTOR": 3, "QUATERNION": 4, "FLOAT4": 4}[attr.data_type]
    field = "value" if attr.data_type in ("FLOAT", "QUATERNION") else "vector"
    out = np.empty(len(obj.data.points) * width, dtype=np.float32)
    attr.data.foreach_get(field, out)
    return out.reshape(-1, width)


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_clouds_have_blenders_own_layout(blank, tmp_path: Path, degree: int) -> None:
    """Every attribute Blender's importer makes, ours makes too, of the same type; positions,
    rotations and SH bit for bit, the exponentials (scale, opacity) within one float32 ulp
    (Blender rounds glibc's expf, we round a float64 exp)."""
    write_ply(random_gaussians(2000, degree, seed=degree), tmp_path / "g.ply")
    ours, theirs = _ours(tmp_path / "g.ply"), _blenders(tmp_path / "g.ply")
    assert ours.type == theirs.type == "POINTCLOUD"
    assert ours.data.type == theirs.data.type == "GAUSSIAN_SPLAT"
    kinds = {a.name: (a.data_type, a.domain) for a in ours.data.attributes}
    for a in theirs.data.attributes:
        assert kinds.get(a.name) == (a.data_type, a.domain), a.name
    for a in theirs.data.attributes:
        got, want = _attribute(ours, a.name), _attribute(theirs, a.name)
        if a.name == "scale":
            np.testing.assert_allclose(got, want, rtol=2.4e-7, atol=0, err_msg=a.name)
        elif a.name == splat_math.NATIVE_BASE:
            np.testing.assert_array_equal(got[:, :3], want[:, :3])
            np.testing.assert_allclose(got[:, 3], want[:, 3], rtol=0, atol=1.2e-7)
        else:
            np.testing.assert_array_equal(got, want, err_msg=a.name)
    assert ours.hide_render and not theirs.hide_render  # ours stays out of F12 unless asked


@pytest.mark.parametrize("engine", ["BLENDER_EEVEE", "CYCLES"])
def test_renders_like_blenders_own_import(blank, tmp_path: Path, engine: str) -> None:
    """The same PLY through our import and Blender's renders alike: EEVEE pixel for pixel,
    Cycles (8 samples, the same seed) within its noise."""
    gen = torch.Generator().manual_seed(5)
    n = 300
    means = (torch.rand(n, 3, generator=gen) - 0.5) * torch.tensor([3.0, 3.0, 1.0])
    g = _splats(means, torch.rand(n, 3, generator=gen), 0.03 + 0.1 * torch.rand(n, 3, generator=gen),
                torch.randn(n, 4, generator=gen), opacity=0.2 + 0.8 * torch.rand(n, generator=gen))  # fmt: skip
    write_ply(g, tmp_path / "g.ply")
    ours, theirs = _ours(tmp_path / "g.ply"), _blenders(tmp_path / "g.ply")
    _camera(blank)
    ours.hide_render, theirs.hide_render = False, True
    a = _render(engine, tmp_path, "ours")
    ours.hide_render, theirs.hide_render = True, False
    b = _render(engine, tmp_path, "theirs")
    assert a[..., :3].mean() > 0.05, "the cloud renders (not black)"
    if engine == "BLENDER_EEVEE":
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    else:
        assert abs(a[..., :3].mean() - b[..., :3].mean()) < 0.01 * b[..., :3].mean()
        assert np.abs(a - b).max() < 0.05


def test_native_cloud_keeps_its_colours_after_reload(blank, tmp_path: Path) -> None:
    obj = pointcloud.create_object("Splats", to_attributes(RED_GREEN), blank.collection)
    assert obj.data.type == "GAUSSIAN_SPLAT" and obj.hide_render
    obj.hide_render = False
    _camera(blank)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "scene.blend"))
    obj = bpy.data.objects["Splats"]
    assert obj.data.type == "GAUSSIAN_SPLAT" and pointcloud.is_gaussians(obj)
    for engine in ("CYCLES", "BLENDER_EEVEE"):
        _assert_red_and_green(_render(engine, tmp_path, f"reloaded-{engine}"))
    back = pointcloud.read_arrays(obj)
    for key, values in to_attributes(RED_GREEN).items():
        if key != "color":
            np.testing.assert_array_equal(back[key].reshape(values.shape), values, err_msg=key)


def test_blenders_own_import_goes_through_render_view_and_export(blank, tmp_path: Path) -> None:
    """A PLY that Blender 5.3 imported itself is a Gaussian object for the add-on: Render View
    draws it as our own import of the same file, and Export PLY writes the file back (SH and
    positions bit for bit; Blender kept only sigmoid(opacity), exp(scale) and the unit
    quaternion, so those come back to float32 rounding)."""
    write_ply(RED_GREEN, tmp_path / "rg.ply")
    theirs = _blenders(tmp_path / "rg.ply")
    assert pointcloud.is_gaussians(theirs)
    _camera(blank)
    cam = blank.camera
    seen = {}
    for tag, obj in (("theirs", theirs), ("ours", _ours(tmp_path / "rg.ply"))):
        result = api.render_views(obj, [cam], tmp_path / tag, enhance=False)
        seen[tag] = read_image(result["views"][0]["image"])  # [3, H, W] sRGB
    img = seen["theirs"]
    assert img.shape == (3, SIZE, SIZE)
    red, green = img[:, SIZE // 2, SIZE // 2 - 8], img[:, SIZE // 2, SIZE // 2 + 7]
    assert red[0] > 0.5 > max(red[1], red[2]) and green[1] > 0.5 > max(green[0], green[2])
    torch.testing.assert_close(seen["theirs"], seen["ours"], atol=2 / 255, rtol=0)

    bpy.context.view_layer.objects.active = theirs
    res, err = run_op(bpy.ops.prosplat.export_ply, filepath=str(tmp_path / "out.ply"))
    assert res == {"FINISHED"}, err
    want = read_ply(tmp_path / "rg.ply", dtype=torch.float64)
    got = read_ply(tmp_path / "out.ply", dtype=torch.float64)
    assert torch.equal(got.means, want.means) and torch.equal(got.sh, want.sh)
    torch.testing.assert_close(got.opacities, want.opacities, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(got.scales, want.scales, rtol=1e-6, atol=0)
    torch.testing.assert_close(got.quats, want.quats / want.quats.norm(dim=1, keepdim=True))


def test_a_failed_native_build_leaves_nothing(blank) -> None:
    """All or nothing: a cloud that cannot be built is removed before the error goes on, and
    the add-on then tries the mesh display, which refuses the same input as clearly."""
    arrays = to_attributes(RED_GREEN)
    arrays["prosplat_view"] = np.zeros(3, np.float32)  # 3 values for 2 points
    before = data_counts()
    with pytest.raises(ValueError, match="'prosplat_view' has 3 values for 2 points"):
        native_splats.create_object("Broken", arrays, blank.collection)
    assert data_counts() == before
    with pytest.raises(ValueError, match="'prosplat_view' has 3 values for 2 points"):
        pointcloud.create_object("Broken", arrays, blank.collection)
    assert data_counts() == before
