"""How far a reconstruction can be trusted, before any view is rendered: leave one input out.

Why (issue 68, item 5): on some captures the model loses to the simplest answer, showing the
nearest photo. On the Middlebury object rings the pasted neighbour scores 3.5-6 dB above the
enhanced view, because the neighbours are a few degrees apart and the geometry falls apart.
A user cannot see that from the views alone until they compare them with photos they do not
have. The inputs themselves are such photos: each input in turn is left out, the scene is
reconstructed from the others, and the input's own camera is rendered (what the product
shows: enhanced when a stage-2 model is loaded, holes filled) and scored against the photo,
beside the photo of its nearest remaining neighbour (MORI's pick) pasted there. When the
render scores below the paste on average, the caller says so in one line and suggests more
photos or closer views.

The estimate is pessimistic by design: a left-out input is farther from the remaining ones
than a target between inputs usually is, and the scene is rebuilt from one view fewer. It runs
at a small size (:data:`TRUST_HEIGHT`), where its cost is that of V small reconstructions.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.data.scene import resize_views
from prosplat.geometry.anchors import DepthAnchors
from prosplat.metrics import psnr
from prosplat.pipeline.enhance import pasted_view

__all__ = ["TRUST_HEIGHT", "TrustEstimate", "leave_one_out"]

#: the height (px) the estimate runs at: the generator's trained size, where a reconstruction
#: of 3 views takes well under a second on 2 cores
TRUST_HEIGHT = 128


@dataclass(frozen=True)
class TrustEstimate:
    """The leave-one-out scores of one set of inputs.

    Attributes:
        views: the input indices that were left out, in order.
        model_psnr: [len(views)] PSNR of the render at each left-out input's camera.
        paste_psnr: [len(views)] PSNR of its nearest remaining neighbour pasted there.
    """

    views: tuple[int, ...]
    model_psnr: tuple[float, ...]
    paste_psnr: tuple[float, ...]

    @property
    def model_db(self) -> float:
        """Mean PSNR of the re-renders, dB (NaN without an estimate)."""
        return sum(self.model_psnr) / len(self.views) if self.views else math.nan

    @property
    def paste_db(self) -> float:
        """Mean PSNR of the pasted neighbours, dB (NaN without an estimate)."""
        return sum(self.paste_psnr) / len(self.views) if self.views else math.nan

    @property
    def margin(self) -> float:
        """Mean PSNR of the render less the paste's, dB (negative: the paste wins)."""
        return self.model_db - self.paste_db

    @property
    def loses_to_paste(self) -> bool:
        return self.margin < 0

    def message(self) -> str | None:
        """One line for the user when the paste wins, else None."""
        if not self.loses_to_paste:
            return None
        return (
            f"warning: on these photos the reconstruction scores {-self.margin:.1f} dB below "
            "simply showing the nearest photo (each input left out in turn and re-rendered); "
            "expect views worse than the photos: add photos between these, or use views "
            "closer to them"
        )

    def as_dict(self) -> dict:
        return {
            "views": list(self.views),
            "model_psnr": list(self.model_psnr),
            "paste_psnr": list(self.paste_psnr),
            "margin_db": None if math.isnan(self.margin) else self.margin,
            "loses_to_paste": self.loses_to_paste,
        }


@torch.no_grad()
def leave_one_out(
    model,
    images: Tensor,
    cameras: Sequence[Camera],
    near: float | None = None,
    far: float | None = None,
    *,
    height: int = TRUST_HEIGHT,
    max_views: int = 4,
    progress: Callable[[int, int], None] | None = None,
    anchors: DepthAnchors | None = None,
) -> TrustEstimate:
    """Each of up to ``max_views`` inputs (evenly spread over ``images [V,3,H,W]``) left out:
    ``model`` (a :class:`~prosplat.ProSplat`) reconstructs the rest at ``height`` px and
    renders the left-out camera as the product shows it (enhanced when it has a stage-2
    model, holes filled), scored by PSNR against the photo beside the paste of the nearest
    remaining input (MORI's pick, :func:`prosplat.pipeline.enhance.pasted_view`).

    Needs at least 3 inputs (2 remain to reconstruct from); with fewer the estimate is empty
    (``margin`` NaN, never a warning). ``progress(k, count)`` is called before the k-th
    left-out input (a caller's progress bar; it may raise to cancel). ``anchors``: as in
    :meth:`~prosplat.ProSplat.reconstruct`, the remaining views' own points each time."""
    cameras = list(cameras)
    v = len(cameras)
    if images.ndim != 4 or images.shape[0] != v:
        raise ValueError(
            f"leave_one_out: images must be [V,3,H,W] with one per camera, got "
            f"{list(images.shape)} for {v} cameras"
        )
    if v < 3:
        return TrustEstimate((), (), ())
    if images.shape[-2] > height:
        images, cameras = resize_views(images, cameras, height)
    count = min(max_views, v)
    left = tuple(sorted({round(k * (v - 1) / max(count - 1, 1)) for k in range(count)}))
    model_scores, paste_scores = [], []
    for k, i in enumerate(left):
        if progress is not None:
            progress(k, len(left))
        rest = [j for j in range(v) if j != i]
        rest_cams = [cameras[j] for j in rest]
        rest_anchors = None if anchors is None else anchors.views(rest)
        rec = model.reconstruct(images[rest], rest_cams, near, far, anchors=rest_anchors)
        view = model.render(
            rec,
            cameras[i],
            images[rest],
            rest_cams,
            enhance=model.improver is not None,
            fill_holes=True,
        )
        truth = images[i]
        model_scores.append(float(psnr(view.image.clamp(0, 1), truth)))
        pasted, _ = pasted_view(cameras[i], images[rest], rest_cams)
        paste_scores.append(float(psnr(pasted.clamp(0, 1), truth)))
    return TrustEstimate(left, tuple(model_scores), tuple(paste_scores))
