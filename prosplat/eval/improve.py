"""The stage-2 ablation (the paper's Table IV) on rendered test scenes, every row in one run.

Each row is a (generator, improvement model or None, reference method) triple; for every
scene and input-view count the generator reconstructs once per distinct generator, and every
row renders and enhances the same target views, so rows differ only in what they change.
The ladder's reference rows (flat colour, MORI paste, true depth) score the same targets.
Scores reuse :class:`prosplat.eval.generator.Score`; ``render_ms`` there is render + MORI +
enhancement per view (the stage-2 cost), ``recon_s`` the generator's forward pass.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from prosplat.data.rigs import pick_inputs
from prosplat.data.scene import SceneData
from prosplat.eval.generator import Score, reference_scores, score_view
from prosplat.pipeline.enhance import render_view


@dataclass
class Row:
    """One ablation row: ``generator`` is a ProSplat (its generator is used), ``improver`` an
    ImproveModel or None (generator only), ``reference`` "paper" or "overlap"."""

    generator: object
    improver: object | None = None
    reference: str = "paper"


def evaluate_rows(
    scene: SceneData,
    rows: dict[str, Row],
    views: list[int],
    dtype: torch.dtype = torch.float32,
    references: tuple[str, ...] | list[str] = (),
) -> list[Score]:
    """Scores of every row on one scene for each input-view count, and the ladder's
    ``references`` rows (:data:`prosplat.eval.generator.REFERENCE_ROWS`) on the same targets."""
    out: list[Score] = []
    name = scene.folder.name if scene.folder else "scene"
    for n in views:
        if n > len(scene.input_indices):
            continue
        idx = pick_inputs(scene, n)
        if references:
            out += reference_scores(scene, idx, references)
        images, cams = scene.images[idx], [scene.cameras[i] for i in idx]
        near, far = float(scene.near[idx].min()), float(scene.far[idx].max())
        cache: dict[int, tuple] = {}
        for label, row in rows.items():
            key = id(row.generator)
            if key not in cache:
                t0 = time.perf_counter()
                g = row.generator.reconstruct(images, cams, near, far, budget="all").gaussians
                cache[key] = (g, time.perf_counter() - t0)
            g, recon_s = cache[key]
            for t in scene.target_indices:
                cam, gt = scene.cameras[t], scene.images[t]
                t1 = time.perf_counter()
                view = render_view(g, cam, images, cams, row.improver,
                                   reference_method=row.reference, dtype=dtype)  # fmt: skip
                ms = (time.perf_counter() - t1) * 1e3
                out.append(
                    score_view(
                        label, n, scene.target_kinds[t], name, view.image, gt, recon_s, ms, len(g)
                    )  # fmt: skip
                )
    return out
