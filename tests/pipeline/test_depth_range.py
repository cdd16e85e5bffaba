"""The depth range's sources in their order, with a real triangulation of a textured plane at
a known depth (z = PLANE_Z) as the reference for the triangulated range."""

from __future__ import annotations

import pytest
import torch
from synthetic_scenes import PLANE_Z, textured_plane_views

from prosplat.geometry.rig import near_far_from_cameras
from prosplat.pipeline.depth_range import depth_range
from prosplat.poses.frame import FAR_MARGIN, NEAR_MARGIN


@pytest.fixture(scope="module")
def plane():
    return textured_plane_views()


def test_triangulated_points_bracket_the_plane_tighter_than_the_cameras(plane):
    images, cams = plane
    r = depth_range(images, cams)
    assert "points triangulated from the 3 inputs" in r.source
    # the plane is seen at 7-8 degrees from its normal: depths of about 2.86-3.15 in these cameras
    assert NEAR_MARGIN * 2.75 < r.near < NEAR_MARGIN * PLANE_Z
    assert FAR_MARGIN * PLANE_Z < r.far < FAR_MARGIN * 3.25
    assert r.anchors is not None and len(r.anchors.observed) == 3
    cam_near, cam_far = near_far_from_cameras(cams)
    assert r.far / r.near < 0.5 * cam_far / cam_near


def test_sources_in_order(plane):
    images, cams = plane
    pts = torch.tensor([[0.0, 0.0, 5.0]] * 40, dtype=torch.float64)
    pts[:, 0] = torch.linspace(-0.5, 0.5, 40)
    # the caller's near/far win; one alone keeps the other estimated
    r = depth_range(images, cams, near=1.0, far=9.0, file_range=(2.0, 3.0))
    assert (r.near, r.far, r.source) == (1.0, 9.0, "near/far given")
    r = depth_range(images, cams, near=0.5, file_range=(2.0, 3.0), given_name="--near/--far")
    assert (r.near, r.far) == (0.5, 3.0) and r.source.startswith("--near/--far + the near/far")
    # the file's own range before any points
    r = depth_range(images, cams, file_range=(2.0, 3.0), points=pts)
    assert (r.near, r.far) == (2.0, 3.0) and r.anchors is None
    # COLMAP points before triangulating: their depth 5, not the plane's 3
    r = depth_range(images, cams, points=pts)
    assert r.near == pytest.approx(NEAR_MARGIN * 5.0, rel=0.02) and "COLMAP points" in r.source
    assert r.anchors.points is pts
    # no triangulation: the cameras
    r = depth_range(images, cams, triangulate=False)
    assert (r.near, r.far) == pytest.approx(near_far_from_cameras(cams))
    assert r.source == "the input cameras" and r.anchors is None


def test_featureless_inputs_fall_back_to_the_cameras(plane):
    _, cams = plane
    r = depth_range(torch.full((3, 3, 192, 192), 0.5), cams)
    assert r.source == "the input cameras"


def test_bad_range_is_refused(plane):
    images, cams = plane
    with pytest.raises(ValueError, match="0 < near < far"):
        depth_range(images, cams, near=3.0, far=2.0)
