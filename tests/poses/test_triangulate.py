"""Sparse points from posed inputs (:func:`prosplat.poses.triangulate_inputs`).

Without Blender: cameras looking at a textured plane, each view rendered exactly by ray-plane
intersection and ``grid_sample``, so every kept point must lie on the plane. With Blender: a
tabletop rendered once per session (``python -m scenes.render --arc 8``: 8 views 13 degrees
apart, 320 px, 8 samples, 10-30 s on 2 cores), checked against its Z-pass depth.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from synthetic_scenes import HALF_EXTENT, PLANE_Z, SIZE, textured_plane_views
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.poses import PoseError, SparsePoints, quiet_colmap, triangulate_inputs
from prosplat.poses import triangulate as triangulate_module


@pytest.fixture(autouse=True, scope="module")
def _quiet():
    quiet_colmap()
    yield
    quiet_colmap(False)


def _assert_observations_inside(result: SparsePoints, cameras: list[Camera]) -> None:
    """Every view's observed points project into that view, in front of it."""
    assert len(result.observed) == len(cameras)
    for seen, cam in zip(result.observed, cameras, strict=True):
        assert seen.dtype == torch.int64 and len(seen) > 0
        assert int(seen.max()) < len(result.points)
        _, _, _, inside = cam.nearest_pixels(result.points[seen])
        assert inside.all()


@pytest.fixture(scope="module")
def plane() -> tuple[Tensor, list[Camera]]:
    return textured_plane_views()


def test_points_of_a_textured_plane_lie_on_it(plane):
    images, cams = plane
    result = triangulate_inputs(images, cams)
    assert result.points.dtype == torch.float64 and result.points.shape[1] == 3
    assert len(result.points) >= 50
    off = (result.points[:, 2] - PLANE_Z).abs() / PLANE_Z
    assert off.median() < 0.01 and (off < 0.03).float().mean() > 0.9
    assert result.points[:, :2].abs().max() < HALF_EXTENT  # on the textured part
    _assert_observations_inside(result, cams)
    assert 0 < result.seconds < 30
    again = triangulate_inputs(images, cams)  # seeded: the same points again
    assert torch.equal(again.points, result.points)


def test_images_above_max_size_are_matched_smaller_on_the_same_plane(plane):
    images, cams = plane
    result = triangulate_inputs(images, cams, max_size=128, num_threads=1)
    assert len(result.points) >= 20
    assert ((result.points[:, 2] - PLANE_Z).abs() / PLANE_Z).median() < 0.01
    _assert_observations_inside(result, cams)  # observations index the full-size views


def test_two_views_suffice(plane):
    """Two inputs give only two-view tracks, which COLMAP's triangulator ignores by default."""
    images, cams = plane
    result = triangulate_inputs(images[[0, 2]], [cams[0], cams[2]])
    assert len(result.points) >= 50
    assert ((result.points[:, 2] - PLANE_Z).abs() / PLANE_Z).median() < 0.01
    _assert_observations_inside(result, [cams[0], cams[2]])


def test_featureless_views_give_no_points_not_an_error(plane):
    _, cams = plane
    result = triangulate_inputs(torch.full((3, 3, SIZE, SIZE), 0.5), cams)
    assert result.points.shape == (0, 3)
    assert [len(o) for o in result.observed] == [0, 0, 0]


def test_wrong_inputs_are_refused(plane):
    images, cams = plane
    with pytest.raises(ValueError, match="at least 2 views"):
        triangulate_inputs(images[:1], cams[:1])
    with pytest.raises(ValueError, match="V cameras"):
        triangulate_inputs(images, cams[:2])
    with pytest.raises(ValueError, match="match"):
        triangulate_inputs(images, [c.resized(SIZE // 2, SIZE // 2) for c in cams])


def test_without_pycolmap_the_call_says_what_to_install(monkeypatch, plane):
    """A fresh copy of the module imported while ``import pycolmap`` fails (the real module
    stays as it is): it imports, and the call names the package to install."""
    monkeypatch.setitem(sys.modules, "pycolmap", None)  # `import pycolmap` raises ImportError
    name = "triangulate_without_pycolmap"
    spec = importlib.util.spec_from_file_location(name, triangulate_module.__file__)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, module)
    spec.loader.exec_module(module)
    assert module.pycolmap is None
    with pytest.raises(PoseError, match="pip install pycolmap"):
        module.triangulate_inputs(*plane)


# ---- against a rendered scene's depth (Blender) ----------------------------------------------
@pytest.fixture(scope="session")
def arc_scene(tmp_path_factory) -> Path:
    pytest.importorskip("bpy")
    out = tmp_path_factory.mktemp("triangulate_scene")
    cmd = [
        sys.executable, "-m", "scenes.render", "--name", "tabletop", "--seed", "10",
        "--out", str(out), "--size", "320", "--inputs", "4", "--arc", "8", "--samples", "8",
    ]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    return out / "tabletop_000010"


@pytest.mark.blender
def test_points_agree_with_the_rendered_depth(arc_scene):
    from prosplat.data import load_scene

    scene = load_scene(arc_scene)
    views = [0, 1, 2, 3]  # adjacent views of the arc
    cams = [scene.cameras[i] for i in views]
    result = triangulate_inputs(scene.images[views], cams)
    assert len(result.points) >= 30
    _assert_observations_inside(result, cams)
    errors = []
    for v, cam in zip(views, cams, strict=True):
        points = result.points[result.observed[views.index(v)]]
        col, row, z, _ = cam.nearest_pixels(points)
        truth = scene.depths[v][row, col].double()  # the Z pass at the nearest pixel
        errors.append((z - truth).abs() / truth)
    assert torch.cat(errors).median() < 0.02
