"""``prosplat eval posed``: any posed set scored on its held-out frames.

The input views (picked as ``prosplat reconstruct`` picks them) are reconstructed once; every
other frame (``--targets`` of them, evenly spread; or the frames of ``--target-set``, another
file in the same world frame such as NeRF synthetic's ``transforms_test.json``) is a target,
read, undistorted and resized the same way, and the predictions are scored against it with
PSNR / SSIM / LPIPS (:mod:`prosplat.metrics`):

* ``flat``: one colour everywhere, the mean colour of the input images;
* ``paste``: the input MORI picks as the reference, resampled to the target's size, as is;
* ``generator``: the generator's render; ``enhanced``: that render after stage 2;
* ``generator filled``: the generator's render with the holes no input saw filled from its
  own colours (:mod:`prosplat.render.hole_fill`; sets on a black background only);
* with ``--refine-steps`` / ``--refine-seconds``, also ``refined``, ``refined filled`` and
  ``refined enhanced``: the same generator Gaussians refined against the inputs, so one run
  shows what refinement buys on the user's own images (the ladder's rows, on data no
  ProSplat scene generator made).

``--input-sets K`` repeats all of it for K choices of input views (:func:`input_sets`) and
reports the mean over every choice's targets, with a column per choice in ``summary.md``
(:func:`per_set_table`): one choice of inputs is one sample.

``views.png`` shows the first targets side by side (ground truth, then each row's image), so
the numbers can be checked by eye.

:func:`score_cases` takes plain tensors (a list of :class:`PosedCase`), so the same rows can
come from any source of posed views.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.eval.generator import Score, markdown_table, score_view, summarise
from prosplat.geometry.anchors import DepthAnchors
from prosplat.pipeline.enhance import OTHER_VIEWS_OPACITY
from prosplat.render.hole_fill import fill_holes

__all__ = [
    "ROWS",
    "PosedCase",
    "contact_sheet",
    "input_sets",
    "per_set_table",
    "score_cases",
    "write_results",
]

ROWS = ("flat", "paste", "generator", "generator filled", "enhanced", "refined", "refined filled",
        "refined enhanced")  # fmt: skip
#: targets shown in ``views.png``
SHEET_TARGETS = 8


class PosedCase(NamedTuple):
    """One evaluation: input ``images [N,3,H,W]`` and ``cameras``, held-out
    ``target_images [T,3,H',W']`` and ``target_cameras``; near/far (None: estimated from the
    cameras), a name for the tables and the depth anchors the inputs observe (None: none)."""

    images: Tensor
    cameras: Sequence[Camera]
    target_images: Tensor
    target_cameras: Sequence[Camera]
    near: float | None = None
    far: float | None = None
    name: str = "posed"
    anchors: DepthAnchors | None = None


def flat_prediction(images: Tensor, camera: Camera) -> Tensor:
    """The inputs' mean colour everywhere, at ``camera``'s size."""
    colour = images.mean(dim=(0, 2, 3))
    return colour[:, None, None].expand(3, camera.height, camera.width).contiguous()


def paste_prediction(
    images: Tensor, cameras: Sequence[Camera], camera: Camera
) -> tuple[Tensor, int]:
    """MORI's reference input for ``camera``, resampled to its size, and its index."""
    from prosplat.pipeline.enhance import pasted_view

    image, ref = pasted_view(camera, images, cameras)
    return image.clamp(0, 1), ref


def score_cases(
    model,
    cases: Sequence[PosedCase],
    *,
    budget: int | float | None = None,
    background: Tensor | None = None,
    reconstruct_kwargs: dict | None = None,
    dtype: torch.dtype = torch.float32,
    sheet: list[list[Tensor]] | None = None,
    other_views_opacity: float = OTHER_VIEWS_OPACITY,
) -> list[Score]:
    """Scores (:class:`prosplat.eval.generator.Score`, ``method`` in :data:`ROWS`) of every target of
    every case. The generator's Gaussians are pruned to ``budget`` as everywhere else;
    ``reconstruct_kwargs`` (refinement: ``refine_steps`` or ``refine_seconds``) add the
    ``refined`` rows, from ``model.reconstruct``. ``enhanced`` rows need ``model.improver``;
    without one they are left out. The ``filled`` rows (the raw render's holes filled from
    its own colours, :mod:`prosplat.render.hole_fill`) need a black ``background`` (None or
    zeros). ``sheet``, when given, receives one list of images per
    target (ground truth, then each prediction in :data:`ROWS` order) for a contact sheet.
    ``other_views_opacity``: as in :meth:`ProSplat.render` (1: every input alike)."""

    rows: list[Score] = []
    enhance = model.improver is not None
    fill = background is None or not bool(torch.as_tensor(background).any())
    for case in cases:
        images, cams = case.images, list(case.cameras)
        n = len(cams)
        t0 = time.perf_counter()
        rec = model.reconstruct(images, cams, case.near, case.far, budget=budget,
                                anchors=case.anchors)  # fmt: skip
        recons = [("generator", "enhanced", rec.gaussians, time.perf_counter() - t0)]
        if reconstruct_kwargs:
            t0 = time.perf_counter()
            g = model.reconstruct(
                images,
                cams,
                case.near,
                case.far,
                budget=budget,
                anchors=case.anchors,
                **reconstruct_kwargs,
            ).gaussians  # the same budget as the generator's
            recons.append(("refined", "refined enhanced", g.detach(), time.perf_counter() - t0))
        for gt, cam in zip(case.target_images, case.target_cameras, strict=True):
            t1 = time.perf_counter()
            flat = flat_prediction(images, cam)
            t2 = time.perf_counter()
            pasted, _ = paste_prediction(images, cams, cam)
            t3 = time.perf_counter()
            preds = [("flat", flat, 0.0, 1e3 * (t2 - t1), 0),
                     ("paste", pasted, 0.0, 1e3 * (t3 - t2), 0)]  # fmt: skip
            for raw_name, enhanced_name, g, recon_s in recons:
                view = model.render(g, cam, images, cams, enhance=enhance,
                                    background=background, dtype=dtype,
                                    other_views_opacity=other_views_opacity)  # fmt: skip
                t = view.timings
                preds.append((raw_name, view.raw, recon_s, t["render_ms"], len(g)))
                if fill:
                    t4 = time.perf_counter()
                    filled = fill_holes(view.raw, view.alpha)
                    ms = t["render_ms"] + 1e3 * (time.perf_counter() - t4)
                    preds.append((f"{raw_name} filled", filled, recon_s, ms, len(g)))
                if enhance:
                    ms = t["render_ms"] + t["mori_ms"] + t["enhance_ms"]
                    preds.append((enhanced_name, view.image, recon_s, ms, len(g)))
            for method, pred, rs, ms, count in preds:
                rows.append(score_view(method, n, "held-out", case.name, pred, gt, rs, ms, count))
            if sheet is not None and len(sheet) < SHEET_TARGETS:
                sheet.append([gt] + [pred for _, pred, *_ in preds])
    return rows


def contact_sheet(sheet: list[list[Tensor]], gap: int = 2) -> Tensor:
    """One image [3,H',W'] of ``sheet`` (rows of same-sized [3,H,W] images) on white."""
    h, w = sheet[0][0].shape[-2:]
    cols = max(len(r) for r in sheet)
    out = torch.ones(3, len(sheet) * (h + gap) - gap, cols * (w + gap) - gap)
    for i, row in enumerate(sheet):
        for j, img in enumerate(row):
            top, left = i * (h + gap), j * (w + gap)
            out[:, top : top + h, left : left + w] = img.detach().float().clamp(0, 1).cpu()
    return out


def write_results(rows: list[Score], out: Path, overwrite: bool = False) -> str:
    """``summary.md`` (the table, returned), ``scores.csv`` and ``scores.json`` (per target)."""
    import csv
    import json
    from dataclasses import asdict, fields

    order = {m: i for i, m in enumerate(ROWS)}
    summary = sorted(summarise(rows), key=lambda s: (s["views"], order.get(s["method"], 99)))
    table = markdown_table(summary)
    out.mkdir(parents=True, exist_ok=True)
    mode = "w" if overwrite else "x"
    with open(out / "summary.md", mode) as fh:
        fh.write(table + "\n")
    with open(out / "scores.json", mode) as fh:
        json.dump({"summary": summary, "targets": [asdict(r) for r in rows]}, fh, indent=1)
    with open(out / "scores.csv", mode, newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=[f.name for f in fields(Score)])
        w.writeheader()
        for r in rows:
            w.writerow(asdict(r))
    return table


def input_sets(posed, inputs: list[int], count: int, fixed: bool = False) -> list[list[int]]:
    """``count`` choices of input views: ``inputs`` (the default choice) first, then
    farthest-point sampling of the camera centres started from frames spread evenly over the
    set, each as many views as ``inputs``; a choice that repeats an earlier one is skipped.

    Why: the result of one choice of inputs is one sample. On the fox photos the same two
    generators differ by -0.7 dB on the default choice and by 0.0 on the mean of seven
    (BENCHMARKS.md, "Generator v8").

    Raises:
        ValueError: ``count`` < 1, or > 1 with ``fixed`` inputs (``--inputs``).
    """
    from prosplat.data.rigs import farthest_point_sampling

    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"--input-sets must be an integer >= 1, got {count!r}")
    if count > 1 and fixed:
        raise ValueError("--input-sets picks its own inputs; drop --inputs (or --input-sets)")
    sets = [list(inputs)]  # as picked (an --inputs order is kept)
    # among distinct camera poses only, as pick_views chooses: coincident cameras are one view
    distinct = [i for i, first in enumerate(posed.first_of_pose()) if first == i]
    n = len(distinct)
    centres = torch.stack([posed.views[i].camera.center.double() for i in distinct])
    for k in range(1, count * 4):  # more starts than asked, in case some repeat
        if len(sets) == count:
            break
        first = (k * n) // count if k < count else (k * n) // (count * 4) % n
        chosen = sorted(distinct[i] for i in farthest_point_sampling(centres, len(inputs), first))
        if all(chosen != sorted(s) for s in sets):
            sets.append(chosen)
    return sets


def per_set_table(rows: list[Score]) -> str:
    """PSNR / LPIPS of every method on every case (a markdown table, cases as columns)."""
    cases = list(dict.fromkeys(r.scene for r in rows))
    methods = [m for m in ROWS if any(r.method == m for r in rows)]
    head = "| method | " + " | ".join(cases) + " |"
    lines = [head, "|---|" + "---:|" * len(cases)]
    for m in methods:
        cells = []
        for c in cases:
            sel = [r for r in rows if r.method == m and r.scene == c]
            psnr = sum(r.psnr for r in sel) / len(sel)
            lp = sum(r.lpips for r in sel) / len(sel)
            cells.append(f"{psnr:.2f} / {lp:.3f}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
