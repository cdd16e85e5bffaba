"""The generator's training settings (:class:`TrainConfig`) and the parsers of its view-count
and size sets: everything a run depends on, checked at construction so a bad setting fails
before the first step. ``prosplat train generator``'s options are made from these fields
(:mod:`prosplat.cli.config_args`), so each field's comment is its ``--help``."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass

from prosplat.generator.config import MAX_ALEXNET_LAYERS
from prosplat.train.common import check_intervals


def input_counts(value: int | str | Sequence[int]) -> tuple[int, ...]:
    """The set of input-view counts a run trains on, sorted and de-duplicated.

    Accepts an int (``2``), a comma-separated string (``"2,4,6"``) or a sequence of ints.

    Raises:
        ValueError: a count outside 2-6 (the generator's range) or text that is not integers.
    """
    if isinstance(value, str):
        try:
            items = [int(v) for v in value.replace(" ", "").split(",") if v]
        except ValueError:
            raise ValueError(
                f"inputs must be a count 2-6 or a comma-separated set like 2,4,6, got {value!r}"
            ) from None
    elif isinstance(value, int):
        items = [value]
    else:
        items = [int(v) for v in value]
    if not items or any(not 2 <= n <= 6 for n in items):
        raise ValueError(f"input-view counts must each be 2-6, got {value!r}")
    return tuple(sorted(set(items)))


def parse_inputs(text: str) -> int | tuple[int, ...]:
    """argparse type for ``--inputs``: ``"4"`` → 4, ``"2,4,6"`` → (2, 4, 6)."""
    try:
        counts = input_counts(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return counts[0] if len(counts) == 1 else counts


def train_sizes(text: str) -> tuple[int, ...]:
    """``"64,128"`` -> (64, 128); each a multiple of 32 (the generator's stride)."""
    try:
        sizes = tuple(sorted({int(v) for v in str(text).replace(" ", "").split(",") if v}))
    except ValueError:
        raise ValueError(
            f"sizes must be comma-separated integers like 64,128, got {text!r}"
        ) from None
    if any(v < 32 or v % 32 for v in sizes):
        raise ValueError(f"training sizes must be multiples of 32, got {text!r}")
    return sizes


DEPTH_LOSSES = ("inverse", "log")


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on; saved beside its checkpoints as ``train_config.json``."""

    # training dataset folder(s) or scene packs (.npz, `prosplat scenes pack`), comma-separated
    data: str
    out: str  # run folder (checkpoints, log.jsonl); the same folder again resumes
    # architecture preset of a new model; prosplat --init weights bring their own
    config: str = "tiny"
    val: str | None = None  # validation dataset folder (optional)
    steps: int = 20_000  # steps of the run (the learning-rate schedule ends here)
    # stop (with a checkpoint) after this step, the schedule still following ``steps``: a long
    # run taken in bounded parts, each part the same steps a single run would take (re-run
    # with a later stop_at, or none, to go on)
    stop_at: int | None = None
    batch: int = 1  # scenes per step per process
    # input views per step: a count 2-6, or a set like 2,4,6 drawn from at each step
    inputs: int | str | tuple[int, ...] = 2
    targets: int = 2  # target views rendered per scene and step
    lr: float = 2e-4  # peak learning rate (linear warm-up, then cosine decay to 10 %)
    weight_decay: float = 0.01  # AdamW's
    lpips_weight: float = 0.05  # weight of LPIPS beside the MSE of the rendered targets
    ssim_weight: float = 0.0  # weight of 1 - SSIM of the rendered targets
    depth_weight: float = 0.0  # rendered vs Blender depth at the targets (see depth_loss)
    # the generator's per-input-view depth maps vs Blender's: direct supervision of the depth
    # head (DepthSplat gets it from a pretrained depth model; see depth_loss)
    input_depth_weight: float = 0.0
    # cross-entropy of the depth head's distribution (its 1/4-resolution logits) against
    # Blender's input depth as a two-hot over the bracketing candidates (see depth_ce): the L1
    # terms above reach the head through the softmax's expectation, whose gradient on a
    # candidate is proportional to that candidate's probability, so a confident wrong peak
    # (an object flattened into the floor behind it) gets almost none; this term pushes the
    # true candidate up whatever mass it has. 0: off
    input_depth_ce_weight: float = 0.0
    # how both depth terms compare depths: "inverse" (L1 of 1/z, in scene units, so scenes of
    # small depth weigh most) or "log" (L1 of log z: the relative error AbsRel scores, the same
    # for a scene at any scale)
    depth_loss: str = "inverse"
    # the input cameras re-rendered from ALL views' Gaussians, scored like targets (colour, and
    # depth with depth_weight): makes the views' Gaussians agree where they see one surface
    input_render_weight: float = 0.0
    # score every render with its holes filled by pull-push (prosplat.render.hole_fill), as the
    # product shows a raw render and stage 2 sees it: a black hole costs more than any surface
    # gains (BENCHMARKS "Holes"), which pushes Gaussians out over what no input saw; filled,
    # a hole costs what the continuation of its surroundings misses
    fill_holes: bool = False
    # image sizes drawn per step, e.g. "64,128" (multiples of 32, at most the data's; empty =
    # the data's size): one set of weights for every size; data is downsampled, never upsampled
    sizes: str = ""
    # render the targets at this multiple of the step's size (at most the data's), e.g. 2 with
    # sizes 64 on 128-px data: the pipeline runs the generator at its trained size and renders
    # its Gaussians for cameras with more pixels, so Gaussians trained only at the input size
    # leave pinholes there
    target_scale: int = 1
    # draw inputs and targets from all of a scene's views, not its input/target split
    any_view: bool = False
    # at a size below the data's, this share of steps crops a window instead of downsampling
    crop_prob: float = 0.0
    # at the data's size, this share of steps crops a window of another shape (see
    # frame_window): other aspect ratios and narrower fields of view than the square renders
    frame_prob: float = 0.0
    # the share of input views given camera effects (exposure, white balance, vignetting,
    # blur, sensor noise, JPEG; prosplat.train.camera_effects) after the step's resize or crop,
    # each effect on or off per view; the targets stay clean, so the generator learns to see
    # through what photographs add to Blender's noise-free renders. 0: off
    camera_effects: float = 0.0
    # the share of views (inputs and targets, each on its own) turned by a quarter turn, their
    # cameras rolled to match (prosplat.train.view_rotation; square steps only): photos come
    # rolled (portrait shots, the Middlebury rings turned by 90 degrees), renders never. 0: off
    roll_prob: float = 0.0
    cache_scenes: int = 32  # decoded scenes kept in memory (raise it where memory allows)
    # start from these weights (a fresh optimiser, step 0): a prosplat generator
    # (.safetensors) trains all of it; a DepthSplat checkpoint (depthsplat-gs-*.pth, README
    # "DepthSplat weights") fine-tunes only its Gaussian regressor and head, the rest frozen
    # (prosplat.train.depthsplat_heads; ``config`` is then unused), and writes
    # OUT/<name>-prosplat-ft.pth for --generator / from_pretrained(generator=)
    init: str | None = None
    # with a prosplat ``init`` without fine matching: add a 1/2-resolution cost volume of this
    # many channels, entering through zero weights so step 0 is the init's generator
    # (prosplat.generator.grow); 0 = the network of ``config``
    grow_fine_matching: int = 0
    # with a prosplat ``init`` without them: add frozen AlexNet relu1..relu<n> features to the
    # monocular branch through zero weights (prosplat.generator.grow.grow_alexnet); 0 = off
    grow_alexnet: int = 0
    # with a prosplat ``init`` without it: add the images' own ZNCC plane sweep with this odd
    # window to the depth head through zero weights (grow.grow_image_matching); 0 = off
    grow_image_matching: int = 0
    # with a prosplat ``init`` without it: add the learned depth sweep over this many band
    # depths after the depth refiner, through a zero convolution (grow.grow_band); 0 = off
    grow_band: int = 0
    grad_clip: float = 0.5  # gradient norm clip
    # > 0: the saved weights are an exponential moving average of the trained ones with this
    # decay (prosplat.train.ema: about the last tenth of its updates, up to 1 / (1 - decay)
    # steps once warmed up, 500 for 0.998 after ~4,500 updates); the raw weights
    # travel in state.pt for resuming, and validation scores the raw ones. 0: off
    ema: float = 0.0
    warmup: int = 500  # steps of linear learning-rate warm-up
    log_every: int = 10  # steps between log.jsonl records
    val_every: int = 1000  # steps between validations (made on logged steps only)
    val_scenes: int = 8  # validation scenes scored
    save_every: int = 500  # steps between checkpoints
    seed: int = 0  # seeds the weights, the data order and every per-step draw
    device: str = "auto"  # auto | cpu | cuda | cuda:N | mps

    def __post_init__(self) -> None:
        check_intervals(self, "log_every", "val_every", "save_every")
        input_counts(self.inputs)  # fail at construction, not at the first step
        if self.depth_loss not in DEPTH_LOSSES:
            raise ValueError(
                f"depth_loss must be one of {list(DEPTH_LOSSES)}, got {self.depth_loss!r}"
            )
        train_sizes(self.sizes)
        if self.stop_at is not None and self.stop_at < 1:
            raise ValueError(f"stop_at must be >= 1, got {self.stop_at}")
        if self.target_scale < 1:
            raise ValueError(f"target_scale must be >= 1, got {self.target_scale}")
        if self.grow_fine_matching < 0:
            raise ValueError(f"grow_fine_matching must be >= 0, got {self.grow_fine_matching}")
        if self.input_depth_ce_weight < 0:
            raise ValueError(
                f"input_depth_ce_weight must be >= 0, got {self.input_depth_ce_weight}"
            )
        for name in ("crop_prob", "frame_prob", "camera_effects", "roll_prob"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if not 0 <= self.ema < 1:
            raise ValueError(f"ema is a decay in [0, 1) (0: off), got {self.ema}")
        if self.frame_prob > 0 and not self.sizes:
            raise ValueError("frame_prob frames the steps drawn at the data's size: give sizes")
        if not 0 <= self.grow_alexnet <= MAX_ALEXNET_LAYERS:
            raise ValueError(
                f"grow_alexnet must be 0-{MAX_ALEXNET_LAYERS}, got {self.grow_alexnet}"
            )
        if self.grow_image_matching < 0 or (
            self.grow_image_matching and self.grow_image_matching % 2 == 0
        ):
            raise ValueError(
                f"grow_image_matching is an odd window (0: off), got {self.grow_image_matching}"
            )
        if self.grow_band < 0 or self.grow_band == 1:
            raise ValueError(f"grow_band is a candidate count >= 2 (0: off), got {self.grow_band}")
        for name in ("grow_fine_matching", "grow_alexnet", "grow_image_matching", "grow_band"):
            if getattr(self, name) and not (self.init or "").endswith(".safetensors"):
                raise ValueError(f"{name} needs --init with prosplat generator weights")

    @property
    def last_step(self) -> int:
        """The step this invocation trains to: ``stop_at`` when set, else ``steps``."""
        return self.steps if self.stop_at is None else min(self.stop_at, self.steps)

    @property
    def size_choices(self) -> tuple[int, ...]:
        """The image sizes steps draw from (empty: the data's own size)."""
        return train_sizes(self.sizes)

    @property
    def view_counts(self) -> tuple[int, ...]:
        """The view counts steps draw from (one element for a fixed count)."""
        return input_counts(self.inputs)
