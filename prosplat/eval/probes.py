"""The views the no-pattern check runs stage 2 on: hazed procedural renders of different
scenes, each with a sharp reference from a nearby camera.

Used by ``tests/improve/test_stage2_no_pattern.py`` on the shipped weights; score a candidate
with :func:`probe_changes` and :func:`probe_scores` before it ships, and it is scored on exactly
the views the test will see. Each view: a sky-to-floor gradient and random ellipses (sharp),
blurred and washed out as the generator's renders of unseen views are;
with a warp-input model the reference lands on a random half-plane, and as in a real warp the
invalid pixels still carry colours (grid_sample's border), never zeros.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.improve.model import ImproveModel
from prosplat.improve.pattern import fixed_pattern_score, lattice_score
from prosplat.pipeline.enhance import enhance


def _scene_image(g: torch.Generator, size: int) -> Tensor:
    """[3,size,size]: a vertical two-colour gradient and 2-6 flat-coloured ellipses."""
    lin = torch.linspace(0, 1, size)
    yy, xx = torch.meshgrid(lin, lin, indexing="ij")
    top, bottom = torch.rand(3, generator=g), torch.rand(3, generator=g)
    img = top[:, None, None] * (1 - yy) + bottom[:, None, None] * yy
    for _ in range(int(torch.randint(2, 7, (1,), generator=g))):
        cy, cx, ry, rx = torch.rand(4, generator=g)
        inside = ((yy - cy) / (0.05 + 0.25 * ry)) ** 2 + ((xx - cx) / (0.05 + 0.25 * rx)) ** 2 < 1
        colour = torch.rand(3, 1, 1, generator=g).expand(3, size, size)
        img = torch.where(inside, colour, img)
    return img


def _orbit(angle: float, size: int) -> Camera:
    eye = [3 * math.cos(angle), 3 * math.sin(angle), 1.0]
    return Camera.look_at(eye, [0, 0, 0], [0, 0, 1], size, size, size)


@torch.no_grad()
def probe_changes(
    improver: ImproveModel | None, views: int = 64, size: int = 64, seed: int = 0
) -> Tensor:
    """[views,3,size,size]: what ``improver`` adds (enhanced - raw) to the probe views.

    ``improver=None`` gives the ideal change instead, the sharp view minus the render: what
    a perfect model would add, and so what the bars must let through (the test checks it).
    """
    g = torch.Generator().manual_seed(seed)
    changes = []
    for _ in range(views):
        sharp = _scene_image(g, size)
        haze = 0.6 * float(torch.rand(1, generator=g))
        blurred = F.avg_pool2d(sharp[None], 9, 1, 4, count_include_pad=False)[0]
        raw = (1 - haze) * blurred + haze * 0.6  # a washed-out render
        angle = 2 * math.pi * float(torch.rand(1, generator=g))
        warp = None
        if improver is None or improver.config.warp_input:
            lin = torch.linspace(-1, 1, size)
            yy, xx = torch.meshgrid(lin, lin, indexing="ij")
            theta = 2 * math.pi * float(torch.rand(1, generator=g))
            valid = (math.cos(theta) * xx + math.sin(theta) * yy > 0).float()
            warp = torch.cat([sharp, valid[None]])
        if improver is None:
            changes.append(sharp - raw)
            continue
        out = enhance(improver, raw, _orbit(angle, size), sharp, _orbit(angle + 0.4, size),
                      alpha=torch.ones(size, size), warp=warp)  # fmt: skip
        if out.shape != raw.shape or not torch.isfinite(out).all():
            raise FloatingPointError("stage 2 gave a non-finite or misshapen view on the probe")
        changes.append(out - raw)
    return torch.stack(changes)


#: What the no-pattern test holds the shipped weights to: each figure stays below its bar.
PROBE_BARS = {"pattern": 3.0, "lattice8": 1.5, "lattice16": 1.5}


def probe_scores(changes: Tensor) -> dict[str, float]:
    """The figures the no-pattern test bounds: mean |change|, and the pattern ratio and 8-
    and 16-px lattice ratios (:data:`PROBE_BARS`)."""
    return {
        "mean_change": float(changes.abs().mean()),
        "pattern": fixed_pattern_score(changes).ratio,
        "lattice8": lattice_score(changes, 8).ratio,
        "lattice16": lattice_score(changes, 16).ratio,
    }
