"""Fine-tuning a DepthSplat checkpoint on Blender scenes: ``prosplat train generator --init
X.pth`` (a released ``depthsplat-gs-*.pth``, or a file this command wrote).

What trains, and why: the paper's joint training keeps DepthSplat's depth model as released
(trained on millions of real video frames, more than a few thousand rendered scenes can
improve) and adapts only how depth and features become Gaussians: the Gaussian regressor and
the Gaussian head (``gaussian_regressor``, ``gaussian_head`` in
:class:`~prosplat.generator.depthsplat.DepthSplatEncoder`; the adapter that turns their
output into Gaussians has no parameters). Everything else -- the multi-view and monocular
depth predictor, the feature upsampler -- is frozen: ``requires_grad`` False and eval mode
whatever ``train()`` is called with, so no norm layer or dropout behaves as in training.
About 0.13 M of small's 38 M values train, so a step costs little more than a forward pass.

Files in the run folder (beside ``log.jsonl`` and ``train_config.json`` as for any run):

- ``checkpoint.safetensors`` + ``state.pt``: the trainable tensors only (encoder key names),
  the step and the optimiser, written by :func:`prosplat.train.common.save_checkpoint`, so a
  resume works as for prosplat's generator (same ``--out``, the frozen rest re-read from
  ``--init``). Its metadata ``format`` is :data:`FORMAT`.
- ``<init stem>-prosplat-ft.pth``: the whole encoder in DepthSplat's released layout (a dict
  with ``state_dict`` keys ``encoder.*``), plus its settings under
  :data:`~prosplat.generator.depthsplat.load.CONFIG_KEY`, rewritten atomically at every save.
  This is the result: ``ProSplat.from_pretrained(generator=...)``, ``prosplat reconstruct
  --generator`` and the add-on's *Generator Weights* read it like a released file (its
  settings, e.g. ``gaussian_scale_max``, travel inside it; the name keeps the released stem so
  the add-on still shows the right licence), and DepthSplat's own code can load its
  ``state_dict``. The licence is the init file's: a fine-tuned base or large file is still
  CC-BY-NC-4.0.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from prosplat.generator.depthsplat import DepthSplatGenerator, save_released_format

#: The modules of :class:`~prosplat.generator.depthsplat.DepthSplatEncoder` that train.
TRAINABLE = ("gaussian_regressor", "gaussian_head")
#: ``format`` in the metadata of a run's ``checkpoint.safetensors``.
FORMAT = "prosplat-depthsplat-heads"
SUFFIX = "-prosplat-ft.pth"


def finetuned_path(out: str | Path, init: str | Path) -> Path:
    """Where a run into ``out`` from ``init`` writes its full ``.pth``."""
    return Path(out) / f"{Path(init).stem}{SUFFIX}"


class HeadTuning(nn.Module):
    """A :class:`DepthSplatGenerator` whose Gaussian regressor and head train and whose other
    modules stay frozen in eval mode. ``forward`` is the generator's (prosplat's interface:
    images [B,V,3,H,W], K [B,V,3,3] pixels, w2c [B,V,4,4], near, far -> GeneratorOutput)."""

    def __init__(self, generator: DepthSplatGenerator):
        super().__init__()
        self.generator = generator
        enc = generator.encoder
        missing = [n for n in TRAINABLE if not hasattr(enc, n)]
        if missing:
            raise ValueError(
                f"this DepthSplat checkpoint has no {', '.join(missing)} (a depth-only file?); "
                "fine-tuning needs a depthsplat-gs-* checkpoint"
            )
        enc.requires_grad_(False)
        for name in TRAINABLE:
            getattr(enc, name).requires_grad_(True)
        self.train()

    @property
    def encoder(self):
        return self.generator.encoder

    def train(self, mode: bool = True) -> HeadTuning:
        """Only the trainable modules follow ``mode``; the frozen ones stay in eval mode."""
        self.training = mode
        self.generator.eval()
        for name in TRAINABLE:
            getattr(self.encoder, name).train(mode)
        return self

    def trainable_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def trainable_state(self) -> dict[str, Tensor]:
        """The trainable tensors under their encoder keys (``gaussian_head.0.weight``, ...)."""
        return {
            f"{name}.{k}": v
            for name in TRAINABLE
            for k, v in getattr(self.encoder, name).state_dict().items()
        }

    def load_trainable(self, state: dict[str, Tensor], source: str = "the checkpoint") -> None:
        """Put a :meth:`trainable_state` back (resume); a run folder of another kind of run
        (prosplat's generator) is an error that says so."""
        want = self.trainable_state()
        if set(state) != set(want) or any(state[k].shape != want[k].shape for k in want):
            raise ValueError(
                f"{source} does not hold this DepthSplat checkpoint's Gaussian heads (another "
                "run's folder, or another --init?); use a new --out"
            )
        with torch.no_grad():
            for k, v in want.items():
                v.copy_(state[k].to(v.device, v.dtype))

    def forward(self, images: Tensor, K: Tensor, w2c: Tensor, near, far):
        return self.generator(images, K, w2c, near, far)

    def save_full(self, path: str | Path, init: str | Path, step: int) -> Path:
        """The whole encoder as a released-layout ``.pth`` with its settings (module doc)."""
        meta = {"init": Path(init).name, "step": int(step), "trained": ",".join(TRAINABLE)}
        return save_released_format(self.encoder, path, config=True, meta=meta)


def load_for_tuning(init: str | Path) -> HeadTuning:
    """``init`` (a DepthSplat ``.pth``) loaded strictly, ready to fine-tune (on the CPU)."""
    from prosplat.generator.depthsplat import load_depthsplat

    return HeadTuning(DepthSplatGenerator(load_depthsplat(init)))
