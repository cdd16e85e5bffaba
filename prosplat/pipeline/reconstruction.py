"""What :meth:`prosplat.ProSplat.reconstruct` returns: one scene's Gaussians and what they
came from.

One type for every way of reconstructing (unpruned, pruned to a budget, refined), so a caller
never pairs the generator's depth maps with cameras of another size, and the timings of each
step travel with the result instead of through per-method fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.gaussians import Gaussians
from prosplat.geometry.anchors import AnchorFit
from prosplat.pipeline.refine import RefineStats

#: The parts :attr:`Reconstruction.timings` times, in the order they run (seconds; 0 for a
#: part that did not run).
TIMED_PARTS = ("generator", "prune", "refine")


@dataclass
class Reconstruction:
    """One scene reconstructed by :meth:`prosplat.ProSplat.reconstruct`.

    Attributes:
        gaussians: the scene's Gaussians: the generator's (one per pixel of its depth maps,
            view-major), pruned to the budget (and flat blocks merged, when
            :attr:`~prosplat.ProSplat.merge_flat` is set), then refined when asked; each one
            tagged with its input view (``gaussians.views``).
        cameras: the input cameras at the size the generator ran at, i.e. the size of
            ``depths`` (the inputs' own size when they were no larger than the generator's
            height, see :meth:`~prosplat.ProSplat.reconstruct`'s ``generator_height``).
        depths: [V,h,w] the generator's depth along each input camera's axis (after the
            depth sweep and its scene-wide factor), at ``cameras``' size.
        view_index: [N] the input view that predicted each Gaussian (refinement's cross-view
            term; equal to ``gaussians.views``).
        prune_stats: the budget's counts (:func:`prosplat.geometry.budget.prune_gaussians`):
            ``input``, ``transparent``, ``out_of_bounds``, ``duplicate``, ``over_budget``,
            ``kept``; with ``budget="all"`` every Gaussian is counted as kept. With
            :attr:`~prosplat.ProSplat.merge_flat` also ``merged``: the Gaussians flat 2x2
            blocks merged away (:func:`prosplat.geometry.merge.merge_flat`), ``kept`` then
            counting what is left.
        refine_stats: what refinement did (:class:`prosplat.pipeline.refine.RefineStats`), or
            None when the Gaussians were not refined.
        anchor_fits: one :class:`~prosplat.geometry.anchors.AnchorFit` per input view when
            ``reconstruct`` had anchors (each view's depth factor and the points' error before
            and after), else empty.
        timings: seconds per part, keys :data:`TIMED_PARTS`: ``generator`` (with its depth
            sweep), ``prune`` (the budget, and the merge when on) and ``refine``.
    """

    gaussians: Gaussians
    cameras: list[Camera]
    depths: Tensor
    view_index: Tensor
    prune_stats: dict[str, int]
    refine_stats: RefineStats | None = None
    timings: dict[str, float] = field(default_factory=lambda: dict.fromkeys(TIMED_PARTS, 0.0))
    anchor_fits: list[AnchorFit] = field(default_factory=list)

    def depths_for(self, images: Tensor) -> Tensor | None:
        """``depths`` when they match ``images [V,3,H,W]`` in size (refinement's depth term
        and MORI's occlusion test need maps at the images' size), else None."""
        return self.depths if self.depths.shape[-2:] == images.shape[-2:] else None
