"""Gaussians as a Blender point cloud: PLY import/export through the operators and how long a
big import takes (the display: test_addon_splat_display.py)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

from addon_support import data_counts, run_op  # noqa: E402
from factories import random_gaussians  # noqa: E402

from addon.blender import native_splats  # noqa: E402
from addon.blender.pointcloud import point_count  # noqa: E402
from prosplat import read_ply, write_ply  # noqa: E402
from prosplat.convert.pointcloud import transform_gaussians  # noqa: E402


def _import(path: Path):
    res, err = run_op(bpy.ops.prosplat.import_ply, filepath=str(path))
    assert res == {"FINISHED"}, err
    return bpy.context.scene.prosplat.gaussians


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_import_export_round_trip_exact(blank, tmp_path: Path, degree: int) -> None:
    write_ply(random_gaussians(3000, degree, seed=degree), tmp_path / "in.ply")
    obj = _import(tmp_path / "in.ply")
    assert point_count(obj) == 3000 and obj["prosplat_kind"] == "gaussians"
    names = {a.name for a in obj.data.attributes}
    k1 = (degree + 1) ** 2 - 1
    if native_splats.supported():  # Blender's own splats, with the PLY's exact values beside
        assert obj.data.type == "GAUSSIAN_SPLAT"
        assert {"opacity", "scale_2", "rot_3", "rotation", "scale", "radiance:base"} <= names
        assert sum(n.startswith("radiance:sh_") for n in names) == k1
    else:  # the mesh display
        assert {"opacity", "scale_2", "rot_3", "f_dc_0", "splat_color"} <= names
        assert sum(n.startswith("f_rest_") for n in names) == 3 * k1
    bpy.context.view_layer.objects.active = obj
    res, err = run_op(bpy.ops.prosplat.export_ply, filepath=str(tmp_path / "out.ply"))
    assert res == {"FINISHED"}, err
    assert (tmp_path / "in.ply").read_bytes() == (tmp_path / "out.ply").read_bytes()


def test_moved_object_exports_moved_gaussians(blank, tmp_path: Path) -> None:
    write_ply(random_gaussians(200, 2), tmp_path / "in.ply")
    obj = _import(tmp_path / "in.ply")
    obj.location = (1.0, 2.0, -0.5)
    obj.rotation_euler = (0.3, -0.2, 1.1)
    obj.scale = (1.5, 1.5, 1.5)
    bpy.context.view_layer.update()
    bpy.context.view_layer.objects.active = obj
    res, err = run_op(bpy.ops.prosplat.export_ply, filepath=str(tmp_path / "moved.ply"))
    assert res == {"FINISHED"}, err
    want = transform_gaussians(read_ply(tmp_path / "in.ply", dtype=torch.float64),
                               np.array(obj.matrix_world))  # fmt: skip
    got = read_ply(tmp_path / "moved.ply", dtype=torch.float64)
    torch.testing.assert_close(got.means, want.means, atol=1e-5, rtol=1e-6)
    torch.testing.assert_close(got.sh, want.sh, atol=1e-5, rtol=1e-5)


def test_non_gaussian_ply_is_refused(blank, tmp_path: Path) -> None:
    (tmp_path / "mesh.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 0\n"
    )
    before = data_counts()
    res, err = run_op(bpy.ops.prosplat.import_ply, filepath=str(tmp_path / "mesh.ply"))
    assert res == {"CANCELLED"} and "no vertex property 'f_dc_0'" in err
    assert "Traceback" not in err and data_counts() == before


def test_export_never_overwrites(blank, tmp_path: Path) -> None:
    write_ply(random_gaussians(10, 0), tmp_path / "in.ply")
    obj = _import(tmp_path / "in.ply")
    bpy.context.view_layer.objects.active = obj
    (tmp_path / "mine.ply").write_bytes(b"precious")
    res, err = run_op(bpy.ops.prosplat.export_ply, filepath=str(tmp_path / "mine.ply"))
    assert res == {"CANCELLED"} and "already exists" in err
    assert (tmp_path / "mine.ply").read_bytes() == b"precious"


def _timed_import(tmp_path: Path, n: int) -> float:
    write_ply(random_gaussians(n, 3), tmp_path / "big.ply")
    t0 = time.perf_counter()
    obj = _import(tmp_path / "big.ply")
    seconds = time.perf_counter() - t0
    assert point_count(obj) == n
    return seconds


def test_import_is_vectorised(blank, tmp_path: Path) -> None:
    """50K degree-3 Gaussians (62 attributes each) import well under the 500K budget's pace."""
    seconds = _timed_import(tmp_path, 50_000)
    assert seconds < 5.0, f"50K Gaussians took {seconds:.2f} s"


@pytest.mark.slow
def test_import_500k_timed(blank, tmp_path: Path) -> None:
    seconds = _timed_import(tmp_path, 500_000)
    print(
        f"\n500K Gaussians (SH 3) PLY import into Blender {bpy.app.version_string}: {seconds:.2f} s"
    )
    assert seconds < 30.0
