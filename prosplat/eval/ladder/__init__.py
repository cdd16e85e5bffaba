"""The evaluation ladder: every answer to "what does this target view look like?", from the
trivial (flat colour, the pasted reference) through per-scene optimisation, the generator and
the enhanced view, to the upper bound (Gaussians at the true input depth), scored on the same
targets with intervals. ``prosplat eval ladder`` runs it; the other evaluations reuse its
rungs (:mod:`prosplat.eval.ladder.rungs`) and intervals (:mod:`prosplat.eval.ladder.stats`).
"""

from prosplat.eval.ladder.geometry import resize_depths, true_depth_gaussians, valid_mask
from prosplat.eval.ladder.run import TargetScore, chosen_overlap, evaluate_scene, score_image
from prosplat.eval.ladder.rungs import (
    REGISTRY,
    LadderContext,
    Rung,
    SceneInputs,
    SkipRung,
    View,
    build_rungs,
    flat_image,
    paste_image,
    register,
)
from prosplat.eval.ladder.stats import Interval, bootstrap_ci, overlap_bin

__all__ = [
    "REGISTRY",
    "Interval",
    "LadderContext",
    "Rung",
    "SceneInputs",
    "SkipRung",
    "TargetScore",
    "View",
    "bootstrap_ci",
    "build_rungs",
    "chosen_overlap",
    "evaluate_scene",
    "flat_image",
    "overlap_bin",
    "paste_image",
    "register",
    "resize_depths",
    "score_image",
    "true_depth_gaussians",
    "valid_mask",
]
