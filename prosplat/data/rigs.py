"""Sparse wide-baseline camera rigs chosen along a trajectory (pure math, no bpy).

The protocol follows MVSplat360 on DL3DV: input views are picked by farthest-point sampling
of camera positions inside a window of the trajectory; target views are the other poses,
labelled *interpolation* when they lie inside the window the inputs span and
*extrapolation* when they lie outside it. Everything is seeded, so a scene's rig is
reproducible from its seed.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from prosplat.core.camera import Camera

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


# ---- photo-like cameras: roll about the viewing axis, a drawn focal length ----------------------


def roll_camera(camera: Camera, degrees: float) -> Camera:
    """``camera`` rolled by ``degrees`` about its own viewing axis (same centre, same optical
    axis, same intrinsics).

    Why: hand-held photo sets are rarely level, while every rendered trajectory keeps the
    horizon level (``Camera.look_at`` with a fixed sky-up); rolled training views keep the
    model from relying on "image up = world up". A positive angle turns the camera
    counter-clockwise as seen from behind it (right-handed about its *backward* axis,
    Blender's local +Z), so the picture's content turns clockwise. In OpenCV axes (x right,
    y down, z forward) the new axes are ``x' = cos(a) x - sin(a) y`` and ``y' = sin(a) x +
    cos(a) y``: the camera's up (``-y``) turns towards its old left (``-x``) by exactly
    ``degrees``. ``degrees == 0`` returns ``camera`` itself, so an unrolled render is
    bit-identical to one made before roll existed.
    """
    if degrees == 0:
        return camera
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    turn = torch.eye(4, dtype=camera.world_to_cam.dtype, device=camera.world_to_cam.device)
    turn[:2, :2] = torch.tensor([[c, -s], [s, c]], dtype=turn.dtype)
    return Camera(camera.K, turn @ camera.world_to_cam, camera.width, camera.height)


def draw_roll(seed: int, view: int, max_degrees: float) -> float:
    """The roll of view ``view`` of scene ``seed`` in degrees, uniform in
    ``[-max_degrees, max_degrees]``; 0.0 when ``max_degrees`` is 0.

    Why its own stream, keyed by (seed, view): the rig, the scene and Cycles' noise use the
    seed's other streams, so turning roll on changes nothing but the cameras' roll, and a
    view's roll does not depend on how many views came before it."""
    if max_degrees < 0:
        raise ValueError(f"max roll must be >= 0 degrees, got {max_degrees}")
    if max_degrees == 0:
        return 0.0
    return random.Random(f"prosplat/roll/{int(seed)}/{int(view)}").uniform(
        -max_degrees, max_degrees
    )


def draw_lens(seed: int, lens_range: tuple[float, float]) -> float:
    """Scene ``seed``'s lens in mm (36 mm sensor), log-uniform in ``lens_range = (A, B)``.

    Why log-uniform: a focal length scales the image, so equal ratios (24 -> 35 mm, 58 -> 85
    mm) are equally different views of the world; uniform in mm would crowd the draws at the
    long end. One lens per scene (its own stream keyed by the seed), as a photo set is mostly
    shot at one zoom setting."""
    lo, hi = lens_range
    if not 0 < lo <= hi:
        raise ValueError(f"lens range must be 0 < A <= B mm, got {lo}-{hi}")
    u = random.Random(f"prosplat/lens/{int(seed)}").random()
    return math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))


def parse_lens_range(text: str) -> tuple[float, float]:
    """``"24-85"`` -> ``(24.0, 85.0)``: the ``--lens-range A-B`` option of ``prosplat scenes
    render`` and of the renderer's worker, checked the same way on both sides.

    Raises:
        ValueError: one line naming the fix for text that is not ``A-B``, a non-positive or
            non-finite lens, or ``B < A``.
    """
    text = str(text).strip()
    if text.startswith("-"):
        raise ValueError(f"--lens-range {text!r}: focal lengths must be > 0 mm")
    first, sep, last = text.partition("-")
    try:
        lo, hi = float(first), float(last)
    except ValueError:
        lo = hi = float("nan")
    if not sep or not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"--lens-range {text!r} is not A-B in mm, e.g. --lens-range 24-85")
    if lo <= 0 or hi <= 0:
        raise ValueError(f"--lens-range {text!r}: focal lengths must be > 0 mm")
    if hi < lo:
        raise ValueError(f"--lens-range {text!r} runs backwards; write the shorter lens first")
    return lo, hi


def parse_roll(text: str) -> float:
    """``"20"`` -> ``20.0``: the ``--roll DEG`` option (largest roll, 0-180 degrees) of
    ``prosplat scenes render`` and of the renderer's worker, checked alike on both sides.

    Raises:
        ValueError: one line naming the fix for anything but a number in [0, 180].
    """
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value <= 180:
        raise ValueError(f"--roll {text!r}: give the largest roll angle, 0-180 degrees")
    return value
