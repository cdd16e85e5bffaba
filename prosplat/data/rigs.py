"""Sparse wide-baseline camera rigs chosen along a trajectory (pure math, no bpy).

The protocol follows MVSplat360 on DL3DV: input views are picked by farthest-point sampling
of camera positions inside a window of the trajectory; target views are the other poses,
labelled *interpolation* when they lie inside the window the inputs span and
*extrapolation* when they lie outside it. Everything is seeded, so a scene's rig is
reproducible from its seed.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from prosplat.data.scene import SceneData

Pose = tuple[Sequence[float], Sequence[float]]  # (eye, look_at)


@dataclass(frozen=True)
class Rig:
    """Indices into the trajectory: ``inputs`` (in trajectory order) and ``targets`` with
    ``target_kinds[i]`` in {"interpolation", "extrapolation"}."""

    inputs: tuple[int, ...]
    targets: tuple[int, ...]
    target_kinds: tuple[str, ...]


def farthest_point_sampling(points: torch.Tensor, k: int, first: int = 0) -> list[int]:
    """Indices of ``k`` points of ``points [T,3]``, each the farthest from those already picked.

    Starts from ``first``; ties resolve to the lowest index, so the result is deterministic.
    No point is picked twice: when every point left coincides with a picked one (fewer
    distinct points than ``k``), the lowest index not yet picked comes next.
    """
    t = points.shape[0]
    if not 1 <= k <= t:
        raise ValueError(f"cannot pick {k} of {t} points")
    chosen = [first]
    dist = (points - points[first]).norm(dim=-1)
    dist[first] = -1.0  # picked: below any distance, so argmax never returns it again
    for _ in range(k - 1):
        nxt = int(torch.argmax(dist))
        chosen.append(nxt)
        dist = torch.minimum(dist, (points - points[nxt]).norm(dim=-1))
        dist[chosen] = -1.0
    return chosen


def choose_rig(
    trajectory: Sequence[Pose], n_inputs: int, n_targets: int, seed: int, window: float = 0.7
) -> Rig:
    """Pick ``n_inputs`` wide-baseline inputs and ``n_targets`` targets from ``trajectory``.

    A window covering ``window`` of the trajectory (seeded offset) holds the inputs, chosen
    by farthest-point sampling from the window's first pose, so they span it. Half of the
    targets (rounded up) are interpolation poses strictly inside the inputs' span, the rest
    extrapolation poses outside it; if one side has too few poses, the other fills in.
    """
    t = len(trajectory)
    if not 2 <= n_inputs <= 6:
        raise ValueError(f"n_inputs must be 2-6 (sparse wide-baseline inputs), got {n_inputs}")
    if n_targets < 0 or n_inputs + n_targets > t:
        raise ValueError(
            f"trajectory has {t} poses; cannot take {n_inputs} inputs + {n_targets} targets"
        )
    rng = random.Random(seed)
    span = max(n_inputs, min(t, round(window * t)))
    start = rng.randint(0, t - span)
    eyes = torch.tensor(
        [list(map(float, p[0])) for p in trajectory[start : start + span]], dtype=torch.float64
    )
    inputs = sorted(start + i for i in farthest_point_sampling(eyes, n_inputs))
    lo, hi = inputs[0], inputs[-1]
    inside = [i for i in range(lo + 1, hi) if i not in inputs]
    outside = [i for i in range(t) if i < lo or i > hi]
    n_in = min(len(inside), (n_targets + 1) // 2)
    n_out = min(len(outside), n_targets - n_in)
    n_in = min(len(inside), n_targets - n_out)
    picks = [(i, "interpolation") for i in rng.sample(inside, n_in)]
    picks += [(i, "extrapolation") for i in rng.sample(outside, n_out)]
    picks.sort()
    return Rig(tuple(inputs), tuple(i for i, _ in picks), tuple(k for _, k in picks))


def arc_rig(
    trajectory: Sequence[Pose], n_views: int, n_inputs: int = 2, fraction: float = 0.25
) -> Rig:
    """``n_views`` poses evenly spaced over the first ``fraction`` of ``trajectory`` (a quarter
    of an orbit's loop: a 90-degree arc, 6 degrees between 16 views), the dense, overlapping
    sweep structure from motion needs (tests of :mod:`prosplat.poses`). ``n_inputs`` of them,
    spread by farthest-point sampling, are the inputs; the rest are interpolation targets."""
    t = len(trajectory)
    if not 2 <= n_views <= t:
        raise ValueError(f"an arc of {n_views} views needs 2-{t} (the trajectory's poses)")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    last = max(n_views - 1, round(fraction * (t - 1)))
    views = sorted({round(k * last / (n_views - 1)) for k in range(n_views)})
    eyes = torch.tensor([list(map(float, trajectory[i][0])) for i in views], dtype=torch.float64)
    inputs = sorted(views[k] for k in farthest_point_sampling(eyes, min(n_inputs, n_views)))
    targets = tuple(i for i in views if i not in inputs)
    return Rig(tuple(inputs), targets, ("interpolation",) * len(targets))


def pick_inputs(scene: SceneData, n: int) -> list[int]:
    """``n`` of the scene's input views, spread by farthest-point sampling of their centres."""
    ins = scene.input_indices
    if n > len(ins):
        raise ValueError(f"{scene.folder}: has {len(ins)} input views, cannot evaluate {n}")
    centers = torch.stack([scene.cameras[i].center for i in ins])
    return sorted(ins[k] for k in farthest_point_sampling(centers, n))
