"""Blending two fine-tunes of one improvement model by interpolating their weights.

Stage 2's fine-tunes trade LPIPS against flicker along a camera path: a heavier LPIPS weight
gives sharper views that flicker more (BENCHMARKS, "Stage 2: a sub-pixel flicker term").
Two fine-tunes that start from the same weights stay in one basin of the loss, so the
weights between them are models too ("model soups", Wortsman et al. 2022), and measured here
they land on the good side of the straight line between the two: the halfway blend of v10
and its LPIPS-0.5 fine-tune has a better PSNR than both. A blend costs no training, so the
trade can be set after the fact, by measurement (the shipped v13 is one: BENCHMARKS
"Stage 2 v13").
"""

from __future__ import annotations

from pathlib import Path

import torch

from prosplat.improve.io import load_improver, save_improver
from prosplat.improve.model import ImproveModel


def blend_improvers(a: ImproveModel, b: ImproveModel, weight: float) -> ImproveModel:
    """A new model with ``(1 - weight) * a + weight * b`` for every floating-point tensor of
    the state (integer buffers are taken from ``a``). ``a`` and ``b`` must share a config
    apart from ``working_size``, an inference setting (``a``'s is kept)."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"blend weight must be in [0, 1], got {weight}")
    ca, cb = a.config, b.config.with_(working_size=a.config.working_size)
    if ca != cb:
        da, db = ca.to_dict(), cb.to_dict()
        differ = sorted(k for k in da if da[k] != db[k])
        raise ValueError(f"the two improvement models have different configs ({differ})")
    sa, sb = a.state_dict(), b.state_dict()
    blended = {
        k: torch.lerp(v, sb[k].to(v.dtype), weight) if v.is_floating_point() else v.clone()
        for k, v in sa.items()
    }
    out = ImproveModel(ca)
    out.load_state_dict(blended)
    return out.eval()


def blend_files(
    a: str | Path,
    b: str | Path,
    weight: float,
    out: str | Path,
    overwrite: bool = False,
    fill_input: bool = False,
) -> Path:
    """:func:`blend_improvers` on two checkpoints, written to ``out`` with the blend (its two
    sources and weight) in the metadata. ``fill_input``: both are loaded as models that see
    the filled render (:attr:`ImproveConfig.fill_input`, no weights of its own), so a model
    fine-tuned with ``--fill`` blends with the one it started from."""
    model = blend_improvers(
        load_improver(a, fill_input=fill_input), load_improver(b, fill_input=fill_input), weight
    )
    return save_improver(
        model, out, overwrite=overwrite, blend=f"(1 - {weight}) * {a} + {weight} * {b}"
    )
