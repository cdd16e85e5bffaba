"""Which input views the generator sees when there are more than it takes.

The generator's cross-view attention takes at most ``config.max_views`` views (6), but a
posed set often has more (NeRF-synthetic has 100, a phone capture dozens). Rather than
failing, reconstruction picks the views itself, in one of two ways:

* ``spread`` (the default): farthest-point sampling over the cameras that see the region of
  interest, so the chosen views surround it as widely as possible (wide baselines are what
  the generator was trained for). The region of interest is the point nearest every optical
  axis: for cameras around an object, its centre. Cameras are compared by centre *and*
  viewing direction, so a rig that only turns on the spot is spread too.
* ``nearest``: the views nearest one camera (the artist's active camera), by position and
  direction: the best texture for that one view, at the cost of coverage elsewhere.

Coincident cameras (the same pose within :data:`COINCIDENT_TOLERANCE`: a frame listed twice,
poses copied from one frame, a static camera filming a moving object) count as one view:
a second image from the same pose adds no baseline, so it is never chosen beside the first
(:func:`distinct_views`), and fewer than 2 distinct poses is refused with a clear message.

Everything here is plain tensors on camera centres and forward vectors (float64), so it is
cheap to test against brute force; :func:`choose_frames` is the worker's entry point, on the
camera dicts of :mod:`prosplat.convert.posed`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from prosplat.convert.posed import camera_from_dict
from prosplat.core.camera import Camera
from prosplat.data.rigs import farthest_point_sampling

__all__ = [
    "COINCIDENT_TOLERANCE",
    "MODES",
    "ViewChoice",
    "axes_focus",
    "choose_frames",
    "choose_views",
    "distinct_views",
    "farthest_views",
    "first_of_pose",
    "nearest_views",
    "sees_point",
]

MODES = ("spread", "nearest")
#: below this (relative to the largest), the axes' normal matrix is singular: the optical
#: axes are (nearly) parallel and meet nowhere, so there is no region of interest to find
_FOCUS_CONDITION = 1e-3
#: two cameras coincide when their centres are closer than this times the rig's size (the
#: largest distance of a centre from the centres' mean) and their viewing directions closer
#: than this many radians (about 0.006 degrees): a step far below any useful baseline, yet
#: far above float rounding of a pose written twice
COINCIDENT_TOLERANCE = 1e-4
#: ... plus this times the centres' distance from the origin: float32 cameras cannot tell
#: centres apart below it, so a rig whose cameras all coincide up to rounding is one pose
_ROUNDING = 1e-6


@dataclass(frozen=True)
class ViewChoice:
    """The chosen views: ``indices`` into the candidates (ascending, the file's order) and a
    sentence saying why, for the reconstruct report."""

    indices: list[int]
    reason: str


def _scale(centers: Tensor) -> float:
    """The rig's size (median distance of the centres to their mean), so that distances
    between centres and differences of directions weigh alike; 1 for coincident centres."""
    d = (centers - centers.mean(0)).norm(dim=1)
    s = float(d.median()) if len(d) else 0.0
    return s if s > 1e-9 else 1.0


def _features(centers: Tensor, forwards: Tensor) -> Tensor:
    """[N,6]: centre over the rig's size, then the unit forward vector."""
    f = forwards / forwards.norm(dim=1, keepdim=True).clamp_min(1e-12)
    return torch.cat([centers / _scale(centers), f], dim=1)


def first_of_pose(
    centers: Tensor, forwards: Tensor, tolerance: float = COINCIDENT_TOLERANCE
) -> list[int]:
    """For each view, the first view (in the given order) whose camera it coincides with:
    itself when no earlier one does.

    Two cameras coincide when their centres are within ``tolerance`` times the rig's size
    (plus float32 rounding of the centres) and their unit viewing directions within
    ``tolerance`` (the chord, about the angle in radians). Roll is ignored: the same centre
    looking the same way sees the same scene. Each view joins the first kept view it
    coincides with, so the grouping depends on nothing but the order.

    Args:
        centers, forwards: [N,3] camera centres and viewing directions.
    """
    c, f = centers.double(), forwards.double()
    f = f / f.norm(dim=1, keepdim=True).clamp_min(1e-12)
    if len(c) == 0:
        return []
    size = float((c - c.mean(0)).norm(dim=1).max())
    reach = tolerance * size + _ROUNDING * (1.0 + float(c.norm(dim=1).max()))
    kept: list[int] = []
    out: list[int] = []
    for i in range(len(c)):
        if kept:
            k = torch.tensor(kept)
            near = ((c[k] - c[i]).norm(dim=1) <= reach) & ((f[k] - f[i]).norm(dim=1) <= tolerance)
            if bool(near.any()):
                out.append(kept[int(near.nonzero()[0, 0])])
                continue
        kept.append(i)
        out.append(i)
    return out


def distinct_views(
    centers: Tensor, forwards: Tensor, tolerance: float = COINCIDENT_TOLERANCE
) -> list[int]:
    """The first view of each group of coincident cameras (:func:`first_of_pose`), ascending:
    all N views when no two coincide."""
    return [i for i, r in enumerate(first_of_pose(centers, forwards, tolerance)) if r == i]


def axes_focus(centers: Tensor, forwards: Tensor) -> Tensor | None:
    """The point nearest every optical axis in the least-squares sense, or None when the axes
    are (nearly) parallel (a forward-facing capture has no such point).

    Solves ``Σ (I − f fᵀ) p = Σ (I − f fᵀ) c``: the sum of squared distances from ``p`` to
    the lines through ``c`` along ``f`` is smallest there. Only points in front of most
    cameras count: a focus behind them is not what they look at.
    """
    c, f = centers.double(), forwards.double()
    f = f / f.norm(dim=1, keepdim=True).clamp_min(1e-12)
    proj = torch.eye(3, dtype=c.dtype) - f[:, :, None] * f[:, None, :]
    a, b = proj.sum(0), (proj @ c[:, :, None]).sum(0)[:, 0]
    ev = torch.linalg.eigvalsh(a)
    if float(ev[0]) <= _FOCUS_CONDITION * float(ev[-1]):
        return None
    p = torch.linalg.solve(a, b)
    in_front = ((p - c) * f).sum(1) > 0
    return p if int(in_front.sum()) * 2 > len(c) else None


def sees_point(cameras: Sequence[Camera], point: Tensor) -> Tensor:
    """[N] bool: ``point`` projects inside each camera's image, in front of it."""
    out = []
    for cam in cameras:
        uv, z = cam.to(dtype=torch.float64).project(point.double()[None])
        u, v = float(uv[0, 0]), float(uv[0, 1])
        out.append(float(z[0]) > 0 and 0 <= u <= cam.width and 0 <= v <= cam.height)
    return torch.tensor(out, dtype=torch.bool)


def farthest_views(centers: Tensor, forwards: Tensor, count: int, first: int = 0) -> list[int]:
    """``count`` views by farthest-point sampling from ``first`` (greedy: each next view is
    the one farthest from all chosen so far, ties to the lowest index), in pick order.

    Greedy sampling is within a factor 2 of the best possible smallest pairwise distance,
    which the tests check against brute force.
    """

    return farthest_point_sampling(_features(centers.double(), forwards.double()), count, first)


def nearest_views(
    centers: Tensor, forwards: Tensor, count: int, center: Tensor, forward: Tensor
) -> list[int]:
    """The ``count`` views nearest the camera at ``center`` looking along ``forward``, nearest
    first: distance between centres (over the rig's size) plus ``1 − cos`` of the angle
    between viewing directions; ties to the lowest index."""
    c, f = centers.double(), forwards.double()
    f = f / f.norm(dim=1, keepdim=True).clamp_min(1e-12)
    t = forward.double() / forward.double().norm().clamp_min(1e-12)
    score = (c - center.double()).norm(dim=1) / _scale(c) + (1 - f @ t)
    order = sorted(range(len(c)), key=lambda i: (float(score[i]), i))
    return order[:count]


def choose_views(
    centers: Tensor,
    forwards: Tensor,
    max_views: int,
    mode: str = "spread",
    sees: Tensor | None = None,
    target: tuple[Tensor, Tensor] | None = None,
) -> tuple[list[int], str]:
    """At most ``max_views`` of N views: all of them when N ≤ ``max_views``, else by ``mode``;
    coincident cameras (:func:`distinct_views`) count as one view, the first of them.

    Args:
        centers, forwards: [N,3] camera centres and viewing directions.
        max_views: the most views the generator takes (``config.max_views``).
        mode: ``spread`` or ``nearest`` (see the module docstring).
        sees: [N] bool, which cameras see the region of interest (None: all); ``spread``
            samples among those when at least 2 do, else among all.
        target: (centre, forward) of the camera to be near (``nearest``; ``spread`` starts
            from the view nearest it when given, else from the first view).

    Returns:
        (indices ascending, a phrase saying how they were chosen).

    Raises:
        ValueError: fewer than 2 views (or distinct poses), an unknown mode, or ``nearest``
            without a target.
    """
    n = len(centers)
    if n < 2:
        raise ValueError(f"reconstruction needs at least 2 input views, got {n}")
    if mode not in MODES:
        raise ValueError(f"unknown view choice {mode!r}; use one of {', '.join(MODES)}")
    if mode == "nearest" and target is None:
        raise ValueError("choosing the views nearest the active camera needs an active camera")
    keep = distinct_views(centers, forwards)
    if len(keep) < 2:
        raise ValueError(
            f"the {n} input views all have the same camera pose; reconstruction needs at least "
            "2 views from different positions or directions: move or turn their cameras apart"
        )
    if len(keep) < n:
        sub = None if sees is None else sees[keep]
        picked, why = choose_views(centers[keep], forwards[keep], max_views, mode, sub, target)
        repeats = f"{n - len(keep)} of the {n} views repeat another's camera pose, left out"
        return [keep[i] for i in picked], f"{why} ({repeats})"
    if n <= max_views:
        return list(range(n)), f"all {n} input views (the generator takes up to {max_views})"
    if mode == "nearest":
        picked = nearest_views(centers, forwards, max_views, *target)
        return sorted(picked), f"the {max_views} of {n} views nearest the active camera"
    pool = list(range(n))
    where = f"the {n} input views"
    if sees is not None and int(sees.sum()) >= 2:
        pool = [i for i in range(n) if bool(sees[i])]
        where = f"the {len(pool)} of {n} views that see the region of interest"
    if len(pool) <= max_views:
        return pool, f"{where} (all of them)"
    first = 0
    if target is not None:
        first = nearest_views(centers[pool], forwards[pool], 1, *target)[0]
    picked = farthest_views(centers[pool], forwards[pool], max_views, first)
    return sorted(pool[i] for i in picked), f"{max_views} spread widely over {where}"


def choose_frames(
    frames: list[dict[str, Any]], max_views: int, choice: dict[str, Any] | None = None
) -> tuple[list[dict[str, Any]], str]:
    """The worker's entry point: frames (``{"name", "image", "camera"}``) cut to at most
    ``max_views``, and a sentence naming the views used and why.

    ``choice``: ``{"mode": "spread" | "nearest", "target": camera dict}`` (None: spread, no
    target). Camera dicts are those of :mod:`prosplat.convert.posed`.
    """

    if not isinstance(frames, list) or not frames:
        raise ValueError("no input views given; an input view needs an image and a camera")
    choice = choice or {}
    cams = [
        camera_from_dict(f.get("camera"), f"input view '{f.get('name', i)}'")
        for i, f in enumerate(frames)
    ]
    centers = torch.stack([c.center.double() for c in cams])
    forwards = torch.stack([c.forward.double() for c in cams])
    target = None
    if choice.get("target") is not None:
        t = camera_from_dict(choice["target"], "the active camera")
        target = (t.center.double(), t.forward.double())
    focus = axes_focus(centers, forwards)
    sees = None if focus is None else sees_point(cams, focus)
    picked, why = choose_views(
        centers, forwards, max_views, choice.get("mode") or "spread", sees, target
    )
    names = [str(frames[i].get("name", i)) for i in picked]
    return [frames[i] for i in picked], f"{why}: {', '.join(names)}"
