"""MORI reference selection: the paper's score, the geometric overlap, and their choice."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera, render
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians, raycast
from prosplat.improve.mori import centre_distances, mori_scores, overlap_scores, select_reference

W, H = 32, 24
FX = 0.5 * W / math.tan(math.radians(30))  # 60° horizontal field of view
UP = (0.0, -1.0, 0.0)


def _cam(eye, direction, scale: float = 1.0) -> Camera:
    eye = torch.tensor(eye, dtype=torch.float64) * scale
    return Camera.look_at(eye, eye + torch.tensor(direction, dtype=torch.float64), UP, FX, W, H)


def _wall_depth(cam: Camera, wall_z: float) -> torch.Tensor:
    """[H, W] analytic z-depth of the plane z = wall_z seen from ``cam`` (0 where missed)."""
    dirs = cam.ray_directions(torch.float64)  # [H, W, 3] unit
    s = (wall_z - cam.center[2]) / dirs[..., 2]
    depth = s * (dirs @ cam.forward)
    return torch.where(s > 0, depth, torch.zeros_like(depth))


def _yaw(deg: float) -> tuple[float, float, float]:
    a = math.radians(deg)
    return (math.sin(a), 0.0, math.cos(a))


def test_paper_case_aligned_far_camera_beats_close_camera_looking_away() -> None:
    target = _cam((0, 0, 0), (0, 0, 1))
    close_away = _cam((2.0, 0, 0), _yaw(180))  # 2 units away, looking backwards
    far_aligned = _cam((0, 0, -3.0), (0, 0, 1))  # 3 units away, same direction
    scores = mori_scores(target, [close_away, far_aligned])
    assert scores.dtype == torch.float64
    torch.testing.assert_close(scores, torch.tensor([0.5, 1 / 3 + 1.0], dtype=torch.float64))
    assert select_reference(target, [close_away, far_aligned]) == 1


def test_centre_distances_are_the_euclidean_distances_of_the_camera_centres() -> None:
    target = _cam((0.5, -1.0, 2.0), (0, 0, 1))
    eyes = [(0.5, -1.0, 2.0), (3.5, 3.0, 2.0), (-1.5, -1.0, -4.0)]
    inputs = [_cam(e, _yaw(40.0 * j)) for j, e in enumerate(eyes)]
    dist = centre_distances(target, inputs)
    assert dist.dtype == torch.float64 and dist.shape == (3,)
    assert torch.allclose(dist, torch.tensor([0.0, 5.0, math.sqrt(40.0)], dtype=torch.float64))
    # the paper's first term is their reciprocal: move input 1 farther and its score falls by it
    far = [inputs[0], _cam((6.5, 7.0, 2.0), _yaw(40.0)), inputs[2]]
    drop = mori_scores(target, inputs)[1] - mori_scores(target, far)[1]
    assert float(drop) == pytest.approx(1 / 5.0 - 1 / 10.0)


def test_coincident_target_selects_that_input_with_finite_scores() -> None:
    target = _cam((0.3, -0.2, 0.1), (0.1, 0, 1))
    same_place_turned = _cam((0.3, -0.2, 0.1), _yaw(40))
    inputs = [
        _cam((1, 0, -1), (0, 0, 1)),
        same_place_turned,
        target,
        _cam((0.31, -0.2, 0.1), (0, 0, 1)),
    ]
    scores = mori_scores(target, inputs)
    assert torch.isfinite(scores).all()
    assert (
        select_reference(target, inputs) == 2
    )  # coincident and aligned beats coincident and turned
    assert scores[2] > scores[1] > scores[3] > scores[0]
    # Every input coincident: the angle alone decides, still finite.
    only = mori_scores(target, [same_place_turned, target])
    assert torch.isfinite(only).all() and select_reference(target, [same_place_turned, target]) == 1


def test_ties_go_to_the_lowest_index() -> None:
    target = _cam((0, 0, 0), (0, 0, 1))
    left, right = _cam((-1, 0, 0), (0, 0, 1)), _cam((1, 0, 0), (0, 0, 1))
    assert select_reference(target, [left, right]) == 0
    assert select_reference(target, [right, left]) == 0


@pytest.mark.parametrize("scale", [1.0, 1000.0])
def test_scene_scale_changes_the_paper_choice_but_not_the_overlap_choice(scale: float) -> None:
    # A: half a unit to the side, turned 45° away; B: two units straight behind, aligned.
    target = _cam((0, 0, 0), (0, 0, 1), scale)
    a = _cam((0.5, 0, 0), _yaw(45), scale)
    b = _cam((0, 0, -2.0), (0, 0, 1), scale)
    depth = _wall_depth(target, 5.0 * scale)
    paper = select_reference(target, [a, b], "paper")
    overlap = overlap_scores(target, depth, [a, b])
    assert paper == (0 if scale == 1.0 else 1)  # 1/0.5 + 0.85 > 1/2 + 1, but not in millimetres
    assert select_reference(target, [a, b], "overlap", target_depth=depth) == 1
    assert overlap[1] == 1.0 and 0.05 < overlap[0] < 0.4  # B sees the whole target view


def test_overlap_identical_away_and_occluded() -> None:
    target = _cam((0.2, 0.1, 0), (0.1, 0, 1))
    behind = _cam((0, 0, -2.0), (0, 0, 1))
    away = _cam((0, 0, 0), (0, 0, -1))
    inputs = [away, target, behind]
    depth = _wall_depth(target, 5.0)
    assert (depth > 0).all()

    scores = overlap_scores(target, depth, inputs)
    assert scores.dtype == torch.float64
    assert scores.tolist() == [0.0, 1.0, 1.0]

    input_depths = torch.stack([_wall_depth(c, 5.0) for c in inputs])
    torch.testing.assert_close(overlap_scores(target, depth, inputs, input_depths), scores)

    # Put an occluder 1 unit in front of `behind` over the left half of its image.
    occluded = input_depths.clone()
    occluded[2, :, : W // 2] = 1.0
    with_occluder = overlap_scores(target, depth, inputs, occluded)
    assert with_occluder[1] == 1.0
    assert 0.3 < with_occluder[2] < 0.7
    assert select_reference(target, inputs, "overlap", depth, occluded) == 1
    # A surface slightly nearer than the point, within rel_tol, does not occlude.
    nearly = input_depths.clone()
    nearly[2] *= 0.97
    assert overlap_scores(target, depth, inputs, nearly)[2] == 1.0
    assert overlap_scores(target, depth, inputs, nearly, rel_tol=0.01)[2] < 0.2


def test_overlap_counts_empty_target_pixels_as_not_overlapping() -> None:
    target = _cam((0, 0, 0), (0, 0, 1))
    depth = _wall_depth(target, 5.0)
    depth[:, : W // 4] = 0.0
    assert overlap_scores(target, depth, [target])[0] == 0.75
    # Nothing rendered at all: no overlap anywhere, so the paper score decides.
    empty = torch.zeros(H, W, dtype=torch.float64)
    inputs = [_cam((3, 0, 0), (0, 0, 1)), _cam((0, 0, -1), (0, 0, 1))]
    assert overlap_scores(target, empty, inputs).tolist() == [0.0, 0.0]
    assert select_reference(target, inputs, "overlap", target_depth=empty) == 1


def test_overlap_on_a_rendered_scene_and_at_another_resolution() -> None:
    cams = orbit_cameras(3, 20, 20)
    gaussians = pixel_aligned_gaussians(cams)
    target = cams[1]
    depth = render(gaussians, target).depth  # float32, alpha-normalised z
    inputs = [cams[0], cams[2], target]
    input_depths = torch.stack([raycast(c)[0] for c in inputs])
    scores = overlap_scores(target, depth, inputs, input_depths)
    assert scores[2] > 0.95 and scores[2] == scores.max()
    assert 0.3 < scores[0] < scores[2] and 0.3 < scores[1] < scores[2]
    assert select_reference(target, inputs, "overlap", depth, input_depths) == 2

    # A depth map at half the camera's resolution is read with the camera rescaled (without
    # input depths: nearest-pixel occlusion lookups at mismatched resolutions are coarse).
    full_scores = overlap_scores(target, raycast(target)[0], inputs)
    half_scores = overlap_scores(target, raycast(target.resized(10, 10))[0], inputs)
    torch.testing.assert_close(half_scores, full_scores, atol=0.05, rtol=0)
    assert half_scores[2] == 1.0


def test_errors_name_the_problem() -> None:
    target = _cam((0, 0, 0), (0, 0, 1))
    depth = _wall_depth(target, 5.0)
    with pytest.raises(ValueError, match="inputs is empty"):
        mori_scores(target, [])
    with pytest.raises(ValueError, match=r"inputs\[1\] must be a prosplat.Camera"):
        mori_scores(target, [target, "camera"])
    with pytest.raises(ValueError, match="target must be"):
        overlap_scores(None, depth, [target])
    broken = _cam((1, 0, 0), (0, 0, 1))
    broken.world_to_cam[0, 3] = float("nan")  # tensors inside a frozen Camera are still mutable
    with pytest.raises(ValueError, match=r"inputs\[0\] has a non-finite pose"):
        select_reference(target, [broken])
    with pytest.raises(ValueError, match="needs target_depth"):
        select_reference(target, [target], "overlap")
    with pytest.raises(ValueError, match="unknown method"):
        select_reference(target, [target], "closest")
    with pytest.raises(ValueError, match="target_depth contains NaN"):
        overlap_scores(target, torch.full((H, W), float("nan")), [target])
    with pytest.raises(ValueError, match=r"input_depths must be \[N=1"):
        overlap_scores(target, depth, [target], torch.ones(2, H, W))
