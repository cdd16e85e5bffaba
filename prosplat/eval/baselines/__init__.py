"""Baselines the feed-forward generator is compared with, on the same sparse inputs.

- :func:`plane_sweep_gaussians`: classical plane-sweep stereo (no learning), one Gaussian
  per input pixel in the generator's layout (view-major, row-major), with depth and
  confidence maps, so the generator's depth can be compared pixel for pixel.
- :func:`optimize_gaussians`: per-scene 3DGS optimisation with the project's rasterizer
  (slow, but the classical quality reference), initialised from the plane sweep or at random.
"""

from prosplat.eval.baselines.optimize import LearningRates, optimize_gaussians
from prosplat.eval.baselines.plane_sweep import (
    gaussians_from_depths,
    plane_sweep_depths,
    plane_sweep_gaussians,
)

__all__ = [
    "LearningRates",
    "gaussians_from_depths",
    "optimize_gaussians",
    "plane_sweep_depths",
    "plane_sweep_gaussians",
]
