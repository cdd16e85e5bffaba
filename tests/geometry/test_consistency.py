"""Tests for prosplat.geometry.consistency.cross_view_check on scenes the tests ray-cast
exactly: a ground plane (z = 0) and, for occlusion, a square hovering above it."""

from __future__ import annotations

import pytest
import torch

from prosplat import Camera, Gaussians
from prosplat.geometry.consistency import (
    CrossViewOptions,
    cross_view_check,
    fade_contradicted,
)
from prosplat.geometry.pixel_gaussians import pixel_gaussians

S = 32  # image size
HW = S * S
#: cameras 4 units above the plane, looking straight down; view 0 covers x in [-2, 2] on the
#: plane, views 1 and 2 lie to its +x side, so view 0's left columns are seen by no other view
EYES = [(0.0, 0.0, 4.0), (1.2, 0.0, 4.0), (1.2, 0.8, 4.0)]


def _cameras(eyes=EYES) -> list[Camera]:
    return [
        Camera.look_at(e, (e[0], e[1], 0.0), (0.0, 1.0, 0.0), fx=S, width=S, height=S) for e in eyes
    ]


def _raycast(cam: Camera, square: float | None = None) -> torch.Tensor:
    """[S,S] float64 z-depth of the plane z = 0 and, with ``square`` = s, of the square
    |x - 0.8|, |y| < s at height 2 in front of it."""
    d = cam.ray_directions(torch.float64)  # [H,W,3] unit, world
    eye = cam.center
    along = d @ cam.forward  # [H,W] depth per unit of ray length
    t = (0.0 - eye[2]) / d[..., 2]  # [H,W] ray length to the plane
    if square is not None:
        t_sq = (2.0 - eye[2]) / d[..., 2]
        hit = eye + t_sq[..., None] * d  # [H,W,3]
        on = ((hit[..., 0] - 0.8).abs() < square) & (hit[..., 1].abs() < square) & (t_sq > 0)
        t = torch.where(on, t_sq, t)
    return t * along


def _depths(cams, square=None) -> torch.Tensor:
    return torch.stack([_raycast(c, square) for c in cams])  # [V,S,S]


def test_true_depths_of_a_plane_drop_nothing():
    """Three views of a plane at its exact depth agree: nothing is dropped, and most pixels
    are seen by another view (so the check did test them)."""
    cams = _cameras()
    res = cross_view_check(_depths(cams), cams)
    assert res.keep.shape == (3 * HW,)
    assert res.keep.all() and res.dropped == 0
    assert (res.contradictions == 0).all()
    assert (res.seen_by > 0).float().mean() > 0.5
    assert res.stats() == {"input": 3 * HW, "dropped": 0, "kept": 3 * HW,
                           "unseen_elsewhere": int((res.seen_by == 0).sum())}  # fmt: skip


def test_floaters_in_front_of_the_plane_are_dropped_exactly():
    """A few pixels of view 0 moved to half their depth (toward the camera, as the curtains
    at depth edges are) float where the other views saw through to the plane: exactly those
    are dropped, as depth-map pixels and as pixel-aligned Gaussians alike."""
    cams = _cameras()
    depths = _depths(cams)
    rows, cols = torch.tensor([14, 15, 16, 17, 18]), torch.tensor([22, 23, 24, 25, 26])
    depths[0, rows, cols] *= 0.5
    floaters = torch.zeros(3 * HW, dtype=torch.bool)
    floaters[rows * S + cols] = True

    res = cross_view_check(depths, cams)
    assert torch.equal(~res.keep, floaters)
    assert (res.contradictions[floaters] >= 1).all()

    # the same on Gaussians built from the maps, checked by their means and view index
    images = torch.rand(3, 3, S, S, dtype=torch.float64)
    g = [pixel_gaussians(images[i], depths[i], cams[i], footprint=0.5, opacity=0.9)
         for i in range(3)]  # fmt: skip
    means = torch.cat([x.means for x in g])  # [3*HW,3]
    view_index = torch.arange(3).repeat_interleave(HW)
    by_means = cross_view_check(depths, cams, means=means, view_index=view_index)
    assert torch.equal(by_means.keep, res.keep)
    assert torch.equal(by_means.contradictions, res.contradictions)

    # a larger margin than the floaters' 50 % lets them through; two votes need two views
    assert cross_view_check(depths, cams, tau=0.6).keep.all()
    two = cross_view_check(depths, cams, min_votes=2)
    assert torch.equal(~two.keep, floaters & (res.contradictions >= 2))


def test_a_pixel_no_other_view_sees_is_kept():
    """A floater in view 0's left columns, which neither other view sees, keeps its own
    confidence: it is kept, with no view counted as seeing it."""
    cams = _cameras()
    depths = _depths(cams)
    depths[0, 10:13, 1] *= 0.5
    res = cross_view_check(depths, cams)
    idx = torch.arange(10, 13) * S + 1
    assert (res.seen_by[idx] == 0).all()
    assert res.keep[idx].all()
    assert res.keep.all()


def test_points_occluded_in_another_view_are_kept():
    """A square above the plane hides part of the plane from each view; the plane points of
    one view that lie behind the square in another are occluded there, not contradicted:
    nothing is dropped, the square's silhouettes included."""
    cams = _cameras()
    depths = _depths(cams, square=0.3)
    assert (depths[0] < 3).any()  # the square is in view 0
    res = cross_view_check(depths, cams)
    assert res.keep.all()

    # some of view 0's plane pixels lie behind the square in view 1 (occluded there)
    pts = cams[0].unproject(cams[0].pixel_centers(torch.float64), depths[0]).reshape(-1, 3)
    col, row, z, inside = cams[1].nearest_pixels(pts)
    occluded = inside & (z > 1.2 * depths[1][row, col])
    assert occluded.sum() > 10
    assert (res.seen_by[:HW][occluded] >= 1).all() and res.keep[:HW][occluded].all()


def test_invalid_depth_is_neither_seen_nor_seeing():
    """A pixel with no depth (0, e.g. sky) is kept, and another view sees nothing there."""
    cams = _cameras()
    depths = _depths(cams)
    depths[1] = 0.0  # view 1 recorded nothing
    depths[0, 16, 24] *= 0.5  # a floater only view 2 can contradict
    res = cross_view_check(depths, cams)
    assert res.keep[HW : 2 * HW].all() and (res.seen_by[HW : 2 * HW] == 0).all()
    assert not res.keep[16 * S + 24]
    assert res.contradictions[16 * S + 24] == 1


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"tau": 1.0}, "tau"),
        ({"min_votes": 0}, "min_votes"),
        ({"view_index": torch.zeros(3 * HW, dtype=torch.long)}, "view_index"),
        ({"means": torch.zeros(4, 2), "view_index": torch.zeros(4, dtype=torch.long)}, "means"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    cams = _cameras()
    with pytest.raises(ValueError, match=match):
        cross_view_check(_depths(cams), cams, **kwargs)


def test_cameras_of_another_size_raise():
    cams = _cameras()
    with pytest.raises(ValueError, match="size"):
        cross_view_check(_depths(cams)[:, :16], cams)


def _floater_scene():
    """View 0 of the plane with 25 pixels moved to half their depth; every view's
    pixel-aligned Gaussians, their view index and the floaters' mask."""
    cams = _cameras()
    depths = _depths(cams)
    rows = torch.arange(12, 17).repeat_interleave(5)
    cols = torch.arange(20, 25).repeat(5)
    depths[0, rows, cols] *= 0.5
    floaters = torch.zeros(3 * HW, dtype=torch.bool)
    floaters[rows * S + cols] = True
    images = torch.rand(3, 3, S, S, dtype=torch.float64)
    g = [pixel_gaussians(images[i], depths[i], cams[i], footprint=0.5, opacity=0.9)
         for i in range(3)]  # fmt: skip
    return cams, depths, Gaussians.cat(g), torch.arange(3).repeat_interleave(HW), floaters


def test_fading_multiplies_the_opacity_once_per_contradicting_view():
    """fade_contradicted: opacity x fade**contradictions, exactly; the Gaussians no view
    contradicts are untouched; fade 0 drops the contradicted ones instead."""
    cams, depths, g, view_index, floaters = _floater_scene()
    res = cross_view_check(depths, cams, 0.1, means=g.means, view_index=view_index)
    assert torch.equal(res.contradictions > 0, floaters)  # both other views see them: 2 votes
    faded, n = fade_contradicted(g, res, 0.3)
    assert n == int(floaters.sum()) == 25 and len(faded) == len(g)
    expected = g.opacities * torch.where(res.contradictions == 2, 0.09, 1.0).to(g.opacities)
    torch.testing.assert_close(faded.opacities, expected)
    assert torch.equal(faded.means, g.means) and torch.equal(faded.sh, g.sh)
    dropped, n0 = fade_contradicted(g, res, 0.0)
    assert n0 == 25 and len(dropped) == len(g) - 25
    assert torch.equal(dropped.means, g.means[~floaters])
    with pytest.raises(ValueError, match="the Gaussians are"):
        fade_contradicted(g[:10], res, 0.3)


@pytest.mark.parametrize(
    "kwargs", [{"tau": 1.0}, {"tau": -0.1}, {"fade": 1.5}, {"fade": float("nan")}]
)
def test_cross_view_options_refuse_values_out_of_range(kwargs):
    with pytest.raises(ValueError, match="must lie in"):
        CrossViewOptions(**kwargs)
