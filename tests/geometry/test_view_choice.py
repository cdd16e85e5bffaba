"""View choice: the fast picks against slow, obvious twins (brute force over subsets)."""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from prosplat import Camera
from prosplat.convert.posed import camera_to_blender_dict
from prosplat.geometry.view_choice import (
    COINCIDENT_TOLERANCE,
    _features,
    axes_focus,
    choose_frames,
    choose_views,
    distinct_views,
    farthest_views,
    first_of_pose,
    nearest_views,
    sees_point,
)


def orbit(n: int, radius: float = 4.0, look=(0.0, 0.0, 0.0), size: int = 32) -> list[Camera]:
    out = []
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = (radius * math.cos(a) + look[0], radius * math.sin(a) + look[1], 1.0 + look[2])
        out.append(Camera.look_at(eye, look, (0, 0, 1), 30.0, size, size))
    return out


def geometry(cams):
    return (
        torch.stack([c.center.double() for c in cams]),
        torch.stack([c.forward.double() for c in cams]),
    )


def random_rig(seed: int, n: int):
    g = torch.Generator().manual_seed(seed)
    centers = torch.randn(n, 3, generator=g, dtype=torch.float64) * 3
    forwards = torch.randn(n, 3, generator=g, dtype=torch.float64)
    return centers, forwards / forwards.norm(dim=1, keepdim=True)


def greedy_twin(feats: torch.Tensor, k: int, first: int) -> list[int]:
    """Farthest-point sampling written the slow way: every candidate against every pick."""
    chosen = [first]
    while len(chosen) < k:
        best, best_d = None, -1.0
        for i in range(len(feats)):
            d = min(float((feats[i] - feats[j]).norm()) for j in chosen)
            if d > best_d:
                best, best_d = i, d
        chosen.append(best)
    return chosen


def min_gap(feats: torch.Tensor, idx) -> float:
    return min(float((feats[a] - feats[b]).norm()) for a, b in itertools.combinations(idx, 2))


@pytest.mark.parametrize("seed", range(6))
def test_spread_matches_greedy_twin_and_is_within_2x_of_best(seed: int) -> None:
    centers, forwards = random_rig(seed, 9)
    feats = _features(centers, forwards)
    got = farthest_views(centers, forwards, 4, first=seed % 9)
    assert got == greedy_twin(feats, 4, seed % 9)
    best = max(min_gap(feats, s) for s in itertools.combinations(range(9), 4))
    assert min_gap(feats, got) >= 0.5 * best - 1e-12
    assert len(set(got)) == 4


@pytest.mark.parametrize("seed", range(4))
def test_nearest_matches_brute_force(seed: int) -> None:
    centers, forwards = random_rig(100 + seed, 10)
    c0, f0 = centers[3] + 0.1, forwards[3]
    scale = float((centers - centers.mean(0)).norm(dim=1).median())
    scores = [float((centers[i] - c0).norm()) / scale + 1 - float(forwards[i] @ f0)
              for i in range(10)]  # fmt: skip
    want = sorted(range(10), key=lambda i: scores[i])[:5]
    assert nearest_views(centers, forwards, 5, c0, f0) == want
    assert want[0] == 3


def test_focus_of_an_orbit_is_its_centre_and_parallel_axes_have_none() -> None:
    centers, forwards = geometry(orbit(8, look=(1.0, -2.0, 0.5)))
    focus = axes_focus(centers, forwards)
    assert focus is not None and torch.allclose(focus, torch.tensor([1.0, -2.0, 0.5]).double(),
                                                atol=1e-9)  # fmt: skip
    line = torch.tensor([[float(i), 0.0, 0.0] for i in range(5)], dtype=torch.float64)
    ahead = torch.tensor([[0.0, 1.0, 0.0]] * 5, dtype=torch.float64)
    assert axes_focus(line, ahead) is None


def test_spread_keeps_to_cameras_that_see_the_region_of_interest() -> None:
    cams = orbit(10)
    # two cameras turned away: they are far apart in the features, but see nothing useful
    for i in (1, 6):
        c = cams[i].center
        cams[i] = Camera.look_at(c.tolist(), (2 * c).tolist(), (0, 0, 1), 30.0, 32, 32)
    centers, forwards = geometry(cams)
    sees = sees_point(cams, torch.zeros(3, dtype=torch.float64))
    assert sees.tolist() == [i not in (1, 6) for i in range(10)]
    picked, why = choose_views(centers, forwards, 6, "spread", sees)
    assert len(picked) == 6 and not {1, 6} & set(picked) and "8 of 10 views that see" in why
    assert picked == sorted(picked)
    # brute force: no 6 of the 8 seeing cameras are spread wider (within greedy's factor 2)
    feats = _features(centers[sees], forwards[sees])
    pool = [i for i in range(10) if sees[i]]
    best = max(min_gap(feats, s) for s in itertools.combinations(range(8), 6))
    assert min_gap(feats, [pool.index(i) for i in picked]) >= 0.5 * best


def test_few_views_are_all_used_and_errors_are_clear() -> None:
    centers, forwards = geometry(orbit(4))
    assert choose_views(centers, forwards, 6)[0] == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="at least 2"):
        choose_views(centers[:1], forwards[:1], 6)
    with pytest.raises(ValueError, match="unknown view choice"):
        choose_views(centers, forwards, 2, "best")
    with pytest.raises(ValueError, match="needs an active camera"):
        choose_views(centers, forwards, 2, "nearest")


def test_choose_frames_on_camera_dicts() -> None:
    cams = orbit(12)
    frames = [{"name": f"v{i}", "image": None, "camera": camera_to_blender_dict(c)}
              for i, c in enumerate(cams)]  # fmt: skip
    chosen, why = choose_frames(frames, 6)
    names = [f["name"] for f in chosen]
    assert len(chosen) == 6 and why.endswith(", ".join(names))
    # greedy from the first: the opposite camera, then the two quarter turns
    assert {"v0", "v3", "v6", "v9"} <= set(names)
    target = camera_to_blender_dict(cams[5])
    near, why = choose_frames(frames, 3, {"mode": "nearest", "target": target})
    assert [f["name"] for f in near] == ["v4", "v5", "v6"] and "nearest the active" in why


def test_coincident_cameras_are_one_pose_within_the_tolerance() -> None:
    """Copies, float32 rounding and roll are one pose; a step of a few tolerances along the
    rig or a turn of a few tolerances is another (the criterion against a slow twin)."""
    cams = orbit(6)
    centers, forwards = geometry(cams)
    size = float((centers - centers.mean(0)).norm(dim=1).max())
    step = 5 * COINCIDENT_TOLERANCE
    turned = forwards[0] + torch.tensor([0.0, 0.0, step], dtype=torch.float64)
    extra_c = torch.stack(
        [
            centers[0],
            centers[1].float().double(),
            centers[0],
            centers[2] + torch.tensor([step * size, 0.0, 0.0], dtype=torch.float64),
        ]
    )
    extra_f = torch.stack([forwards[0], forwards[1].float().double(), turned, forwards[2]])
    c, f = torch.cat([centers, extra_c]), torch.cat([forwards, extra_f])
    assert first_of_pose(c, f) == [0, 1, 2, 3, 4, 5, 0, 1, 8, 9]
    assert distinct_views(c, f) == [0, 1, 2, 3, 4, 5, 8, 9]
    # a camera rolled about its axis sees the same scene: same centre and forward
    rolled = Camera.look_at(cams[3].center.tolist(), (0, 0, 0), (0, 1, 1), 30.0, 32, 32)
    c2, f2 = geometry([*cams, rolled])
    assert first_of_pose(c2, f2)[-1] == 3
    # the slow twin: every pair against the tolerances, first match wins
    reach = COINCIDENT_TOLERANCE * float((c - c.mean(0)).norm(dim=1).max())
    reach += 1e-6 * (1 + float(c.norm(dim=1).max()))
    fn = f / f.norm(dim=1, keepdim=True)
    twin: list[int] = []
    for i in range(len(c)):
        kept = [j for j in range(i) if twin[j] == j]
        same = [j for j in kept if float((c[j] - c[i]).norm()) <= reach
                and float((fn[j] - fn[i]).norm()) <= COINCIDENT_TOLERANCE]  # fmt: skip
        twin.append(same[0] if same else i)
    assert first_of_pose(c, f) == twin


def test_farthest_views_never_repeat_a_view() -> None:
    """Fewer distinct poses than asked: the sampling goes on with views not yet picked
    instead of picking the first one again (it returned 0, 0, 0, 0 on one pose)."""
    centers = torch.zeros(5, 3, dtype=torch.float64)
    forwards = torch.tensor([[0.0, 0.0, 1.0]] * 5, dtype=torch.float64)
    assert farthest_views(centers, forwards, 4) == [0, 1, 2, 3]


def test_coincident_views_are_never_chosen_twice() -> None:
    centers, forwards = geometry(orbit(12))
    # views 12-19: copies of views 0, 3, 6 and 9 (a frame listed twice, a static camera)
    copies = [0, 3, 6, 9, 0, 3, 6, 9]
    c, f = torch.cat([centers, centers[copies]]), torch.cat([forwards, forwards[copies]])
    for mode, target in (("spread", None), ("nearest", (centers[5], forwards[5]))):
        picked, why = choose_views(c, f, 6, mode, None, target)
        assert len(set(picked)) == 6 and all(i < 12 for i in picked), (mode, picked)
        assert "8 of the 20 views repeat another's camera pose" in why
    # few views: each distinct pose once, the first of each
    picked, why = choose_views(c[[0, 12, 3, 13]], f[[0, 12, 3, 13]], 6)
    assert picked == [0, 2] and "all 2 input views" in why


def test_one_pose_is_refused_clearly() -> None:
    centers, forwards = geometry(orbit(4))
    same_c, same_f = centers[[1, 1, 1, 1]], forwards[[1, 1, 1, 1]]
    with pytest.raises(ValueError, match="the 4 input views all have the same camera pose"):
        choose_views(same_c, same_f, 6)
    cam = camera_to_blender_dict(orbit(4)[1])
    frames = [{"name": f"v{i}", "image": None, "camera": cam} for i in range(3)]
    with pytest.raises(ValueError, match="same camera pose.*move or turn"):
        choose_frames(frames, 6)
