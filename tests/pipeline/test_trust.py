"""prosplat.pipeline.trust: the leave-one-out estimate warns where showing the nearest photo
would beat the reconstruction, and not where the reconstruction wins.

The references: the ray-cast analytic scene (:mod:`prosplat.eval.demo_scene`), seen from a
wide arc (the neighbours' photos are far from each other: pasting one is poor) and from a
tight cluster of cameras (every photo is nearly the others: pasting one is nearly exact)."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import render
from prosplat.cli.reconstruct import trust_line
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
from prosplat.pipeline.trust import TrustEstimate, leave_one_out

SIZE = 64


def views(arc_deg: float):
    cams = orbit_cameras(4, SIZE, SIZE, arc_deg=arc_deg)
    truth = pixel_aligned_gaussians(orbit_cameras(9, 2 * SIZE, 2 * SIZE, arc_deg=60.0))
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    return images, cams


def test_a_wide_arc_gets_no_warning_and_a_tight_cluster_does(shipped_generator):
    wide = leave_one_out(shipped_generator, *views(60.0))
    assert wide.views == (0, 1, 2, 3) and len(wide.model_psnr) == 4
    assert not wide.loses_to_paste and wide.message() is None, wide
    assert "no warning" in trust_line(wide)
    calls = []
    tight = leave_one_out(
        shipped_generator, *views(1.0), progress=lambda k, n: calls.append((k, n))
    )
    assert calls == [(0, 4), (1, 4), (2, 4), (3, 4)]
    assert tight.loses_to_paste, tight
    assert "below simply showing the nearest photo" in tight.message()
    assert f"{-tight.margin:.1f} dB" in trust_line(tight)


def test_too_few_inputs_give_no_estimate_and_bad_inputs_raise(shipped_generator):
    images, cams = views(40.0)
    empty = leave_one_out(shipped_generator, images[:2], cams[:2])
    assert empty.views == () and math.isnan(empty.margin) and empty.message() is None
    assert "fewer than 3 inputs" in trust_line(empty)
    with pytest.raises(ValueError, match="one per camera"):
        leave_one_out(shipped_generator, images[:3], cams)
    assert TrustEstimate((0,), (12.0,), (10.0,)).as_dict()["margin_db"] == 2.0
