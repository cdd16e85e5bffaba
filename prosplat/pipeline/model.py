"""The user-facing entry point: posed images in, Gaussians out, enhanced views of any camera.

    >>> model = ProSplat.from_pretrained()            # shipped weights (or a path)
    >>> rec = model.reconstruct(images, cameras)      # images [N,3,H,W] in [0,1]
    >>> rec.gaussians, rec.timings                    # a Reconstruction: Gaussians, depths, ...
    >>> view = model.render(rec, camera, images)      # view.image: enhanced [3,H,W]

:meth:`ProSplat.reconstruct` is the one way to reconstruct (its options pick the budget and
refinement); :meth:`ProSplat.run_generator` is the network alone, for training and tests.

Checkpoints are safetensors files holding the generator's weights and, in the metadata, the
:class:`~prosplat.generator.GeneratorConfig` as JSON, so a file always rebuilds its own network.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.checkpoints import read_checkpoint, write_checkpoint
from prosplat.core.gaussians import Gaussians
from prosplat.core.image_io import check_images
from prosplat.data.scene import resize_views, resized_width
from prosplat.generator import TINY, Generator, GeneratorConfig, GeneratorOutput
from prosplat.geometry.anchors import AnchorFit, DepthAnchors, anchor_depths
from prosplat.geometry.budget import prune_pixel_aligned
from prosplat.geometry.consistency import CrossViewOptions, cross_view_check, fade_contradicted
from prosplat.geometry.depth_edges import EdgeOptions
from prosplat.geometry.merge import MergeOptions, merge_flat
from prosplat.geometry.pixel_gaussians import slide_gaussians
from prosplat.geometry.rig import near_far_from_cameras
from prosplat.pipeline.depth_sweep import (
    DepthSweepOptions,
    scale_search,
    slide_along_rays,
    snap_output,
)
from prosplat.pipeline.edges import resolve_output
from prosplat.pipeline.enhance import EnhancedView, render_view
from prosplat.pipeline.reconstruction import Reconstruction
from prosplat.pipeline.refine import check_budget, refine
from prosplat.pipeline.refine import check_images as check_refine_inputs

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
DEFAULT_WEIGHTS = WEIGHTS_DIR / "generator_tiny.safetensors"
TRAIN_COMMAND = "prosplat train generator --config tiny --data DIR"
CHECKPOINT_FORMAT = "prosplat-generator"
#: Suffixes of PyTorch pickles: a generator file with one is a DepthSplat checkpoint (its
#: released files, or prosplat's fine-tune of one); prosplat's own generators are safetensors.
DEPTHSPLAT_SUFFIXES = (".pth", ".pt", ".ckpt")

#: The image size (pixels, the short side) the shipped weights were trained at (v5-v7: 64 and
#: 128 px): the generator runs at most this high, and ``prosplat reconstruct`` loads its inputs
#: at this size by default. ``prosplat demo`` runs at 64 px (``demo.DEMO_SIZE``) to stay fast.
TRAINED_SIZE = 128

#: :meth:`ProSplat.reconstruct` places Gaussians at most this many times the matching height
#: (512 px for the shipped weights). At 512 px on the 6 test scenes 4x against 2x gave the
#: enhanced view 19.28 dB / LPIPS 0.351 against 19.02 / 0.407 and the filled raw view LPIPS
#: 0.346 against 0.395 at level PSNR (both with the depth ramps dropped; BENCHMARKS.md,
#: "Artist resolution"), and 4 inputs reconstruct in 1.3 s on 2 cores ("Speed at artist
#: sizes"); larger inputs are resized to it first, since a 1080p camera's inputs would make
#: 2 M Gaussians a view.
MAX_GAUSSIAN_SCALE = 4


def is_depthsplat_file(path: str | Path | None) -> bool:
    """Whether a generator file given as one path (the add-on's *Generator Weights*, the
    worker's ``weights``) goes to ``from_pretrained(generator=...)``: decided by the suffix,
    which costs nothing and needs no torch.load of a file that may be 1.4 GB."""
    return path is not None and Path(str(path)).suffix.lower() in DEPTHSPLAT_SUFFIXES


def _load_improver(improve: str | Path | bool | None):
    """The improvement model ``from_pretrained(improve=...)`` asks for (see there)."""
    if improve is False:
        return None
    from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS, load_improver

    if improve is None or improve is True:
        if not DEFAULT_IMPROVE_WEIGHTS.is_file():
            if improve is True:
                raise FileNotFoundError(
                    f"no shipped improvement-model weights ({DEFAULT_IMPROVE_WEIGHTS} is missing); "
                    "train them with `prosplat train improve` and pass improve=PATH"
                )
            return None
        return load_improver(DEFAULT_IMPROVE_WEIGHTS)
    return load_improver(improve)


class ProSplat:
    """ProSplat: the generator (stage 1) and, when loaded, the improvement model (stage 2).

    ``ProSplat(config)`` builds a randomly initialised generator (seed torch first for a
    reproducible one) and no improvement model; :meth:`from_pretrained` loads weights.
    ``model.improver`` is the stage-2 :class:`~prosplat.improve.ImproveModel` or None;
    ``model.trained_size`` the height the generator was trained at (``TRAINED_SIZE`` for the
    shipped weights; a file's ``trained_size`` metadata; else None), at most which
    :meth:`reconstruct` runs it.
    """

    def __init__(
        self,
        config: GeneratorConfig | None = None,
        device=None,
        improver=None,
        generator=None,
        trained_size: int | None = None,
    ) -> None:
        if (
            generator is not None
        ):  # a ready generator, e.g. DepthSplat (from_pretrained(generator=))
            self.config = generator.config
            self.generator = generator.to(device if device is not None else "cpu")
        else:
            self.config = TINY if config is None else config
            self.generator = Generator(self.config).to(device if device is not None else "cpu")
        self.generator.eval()
        #: the image height the generator was trained at (None: unknown); the pipeline runs
        #: the generator at most this high (:meth:`reconstruct`'s ``generator_height``)
        self.trained_size = trained_size
        #: place the Gaussians at the inputs' own size when the generator matches at a smaller
        #: one (:meth:`reconstruct`); False: at the matching size, as before 2026-11-24
        self.full_res_gaussians = True
        #: a local plane sweep around the generator's depth (:mod:`prosplat.pipeline.depth_sweep`) moves
        #: its Gaussians to where the inputs match (:meth:`reconstruct`); None: off
        self.depth_sweep = None
        #: the ramps of the depth map between two surfaces resolved after the sweep
        #: (:mod:`prosplat.geometry.depth_edges`), so that no curtain of Gaussians hangs
        #: between them; None: off
        self.depth_edges: EdgeOptions | None = None
        #: the cross-view check (:mod:`prosplat.geometry.consistency`): each Gaussian's
        #: opacity fades by ``fade`` per other input view that saw through it, before the
        #: budget's survivors are merged; None (the default): off. On the twelve 512-px test
        #: scenes ``CrossViewOptions()`` took the floaters from 12.7 % to 8.9 % at +0.09 dB
        #: (open scenes -0.3 dB, near-far +1.1), but -0.5 dB on eight real photo sets;
        #: BENCHMARKS "Cross-view check"
        self.cross_view: CrossViewOptions | None = None
        #: Gaussians come at most this many times the matching height (:meth:`_generate`)
        self.max_gaussian_scale: float = MAX_GAUSSIAN_SCALE
        #: merge the budget's survivors in flat 2x2 pixel blocks into one Gaussian each
        #: (:func:`prosplat.geometry.merge.merge_flat`), when the Gaussians were placed at
        #: more than ``above_scale`` times the matching size (so at 512 px, not at 128);
        #: None (the default): off. At 512 px on 6 test scenes ``MergeOptions()`` kept 35 %
        #: fewer Gaussians (951K -> 620K) at level filled-view PSNR and LPIPS, but the views
        #: draw no faster (merged Gaussians grow to keep their coverage) and the merge costs
        #: about as much as the budget, so it is opt-in for memory, PLY size and the
        #: viewport (BENCHMARKS.md, "Merging flat blocks")
        self.merge_flat: MergeOptions | None = None
        self.improver = improver
        if improver is not None:
            improver.to(self.device).eval()

    @property
    def device(self) -> torch.device:
        return self.generator.device

    def to(self, device) -> ProSplat:
        self.generator.to(device)
        if self.improver is not None:
            self.improver.to(device)
        return self

    # ---- checkpoints ------------------------------------------------------------------------
    @classmethod
    def from_pretrained(
        cls,
        path: str | Path | None = None,
        config: GeneratorConfig | None = None,
        device=None,
        improve: str | Path | bool | None = None,
        *,
        generator: str | Path | None = None,
        generator_size: tuple[int, int] | None = None,
        depth_sweep=None,
    ) -> ProSplat:
        """Load a checkpoint written by :meth:`save` (or the training command).

        Args:
            path: a ``.safetensors`` file; None loads the shipped ``generator_tiny`` weights.
            generator: instead of ``path``, a DepthSplat checkpoint (a released
                ``depthsplat-gs-*.pth``, see README "DepthSplat weights"), loaded strictly by
                :func:`prosplat.generator.depthsplat.load_depthsplat`; ``generator_size``
                (H, W) fixes its resolution (default: each input rounded to the sizes it
                accepts).
            config: only needed for a file without config metadata; if both are present they
                must agree.
            device: where to put the model (default CPU).
            improve: the stage-2 checkpoint: None loads the shipped ``improve_tiny`` weights
                when they exist (else no improvement model), a path loads that file, False
                loads none.
            depth_sweep: :attr:`depth_sweep`: None, the default, is on
                (:class:`~prosplat.pipeline.depth_sweep.DepthSweepOptions`) for prosplat generators,
                whose depth it measurably improves (BENCHMARKS.md, "Depth sweep"), and off for
                DepthSplat, where it is not measured; True / False force it on / off, and a
                ``DepthSweepOptions`` sets it.
        """
        if depth_sweep is True or (depth_sweep is None and generator is None):
            depth_sweep = DepthSweepOptions()
        elif depth_sweep is False or depth_sweep is None:
            depth_sweep = None
        elif not isinstance(depth_sweep, DepthSweepOptions):
            raise ValueError(
                "depth_sweep must be None, True, False or a DepthSweepOptions, got "
                f"{type(depth_sweep).__name__}"
            )
        else:
            depth_sweep.check()
        if generator is not None:
            if path is not None or config is not None:
                raise ValueError(
                    "pass either path=/config= (a prosplat generator) or generator= (DepthSplat)"
                )
            from prosplat.generator.depthsplat import DepthSplatGenerator, load_depthsplat

            gen = DepthSplatGenerator(load_depthsplat(generator), size=generator_size)
            model = cls(device="cpu", improver=_load_improver(improve), generator=gen)
            model.depth_sweep = depth_sweep
            return model.to(device) if device is not None else model
        if path is None:
            path = DEFAULT_WEIGHTS
            if not path.is_file():
                raise FileNotFoundError(
                    f"no shipped generator weights yet ({path} is missing); train them with "
                    f"`{TRAIN_COMMAND}` and pass the checkpoint as path=, or use ProSplat(config) "
                    "for an untrained model"
                )
        path = Path(path)
        state, meta = read_checkpoint(path, "generator")
        stored = GeneratorConfig.from_json(meta["config"]) if "config" in meta else None
        if stored is None and config is None:
            raise ValueError(
                f"{path} has no generator config in its metadata; pass config= (e.g. prosplat.generator.TINY)"
            )
        if stored is not None and config is not None and stored != config:
            raise ValueError(
                f"{path} was saved with a different generator config than the one passed; drop config= "
                f"to use the file's ({stored.to_json()})"
            )
        # the shipped file carries it too (tests/pipeline/test_refine_wiring.py holds it to TRAINED_SIZE)
        trained = meta.get("trained_size")
        model = cls(
            stored or config,
            device="cpu",
            improver=_load_improver(improve),
            trained_size=int(trained) if trained else None,
        )
        try:
            model.generator.load_state_dict(state, strict=True)
        except RuntimeError as e:
            raise ValueError(f"{path} does not match the generator it describes: {e}") from e
        model.depth_sweep = depth_sweep
        if device is not None:
            model.to(device)
        return model

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write weights + config to ``path`` atomically (a temp file in the same folder, then a
        rename), never replacing an existing file unless ``overwrite``."""
        if not isinstance(self.generator, Generator):
            raise ValueError(
                "save() writes prosplat generators; a DepthSplat generator stays in its own file"
            )
        meta = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_json(),
            "parameters": json.dumps(self.generator.num_parameters()),
        }
        if self.trained_size:
            meta["trained_size"] = str(int(self.trained_size))
        return write_checkpoint(self.generator.state_dict(), path, meta, overwrite)

    # ---- inference --------------------------------------------------------------------------
    def _inputs(
        self, images: Tensor, cameras: Sequence[Camera], near, far
    ) -> tuple[Tensor, Tensor, Tensor, float, float]:
        if not isinstance(images, Tensor) or images.ndim != 4 or images.shape[1] != 3:
            shape = list(images.shape) if isinstance(images, Tensor) else type(images).__name__
            raise ValueError(f"images must be a [N,3,H,W] tensor in [0,1], got {shape}")
        check_images(images, "images")
        cameras = list(cameras)
        if len(cameras) != images.shape[0]:
            raise ValueError(
                f"got {images.shape[0]} images but {len(cameras)} cameras; give one camera per image"
            )
        h, w = images.shape[-2:]
        for i, cam in enumerate(cameras):
            if not isinstance(cam, Camera):
                raise ValueError(
                    f"cameras[{i}] must be a prosplat.Camera, got {type(cam).__name__}"
                )
            if (cam.width, cam.height) != (w, h):
                raise ValueError(
                    f"cameras[{i}] is {cam.width}x{cam.height} but the images are {w}x{h}; "
                    "use camera.resized(W, H) when resizing images"
                )
        if near is None or far is None:
            d_near, d_far = near_far_from_cameras(cameras)
            near = d_near if near is None else near
            far = d_far if far is None else far
        K = torch.stack([c.K.float().cpu() for c in cameras])[None]  # [1,N,3,3]
        w2c = torch.stack([c.world_to_cam.float().cpu() for c in cameras])[None]  # [1,N,4,4]
        return images[None], K, w2c, float(near), float(far)

    def reconstruct(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        *,
        budget: int | float | str | None = None,
        refine_steps: int | None = None,
        refine_seconds: float | None = None,
        refine_options=None,
        seed: int = 0,
        progress=None,
        cancel=None,
        generator_height: int | None = None,
        depth_scale: bool = True,
        grad: bool = False,
        anchors: DepthAnchors | None = None,
    ) -> Reconstruction:
        """Reconstruct one scene: the generator, the Gaussian budget, then (when asked)
        refinement against the inputs; the one entry point for every way of doing it.

        Args:
            images: [N,3,H,W] float in [0, 1], one :class:`Camera` (W x H) each in ``cameras``.
            near, far: the scene's depth range; None derives it from the cameras
                (:func:`prosplat.geometry.rig.near_far_from_cameras`).
            budget: how many of the generator's Gaussians to keep
                (:func:`prosplat.geometry.budget.prune_gaussians`): None, the default, the
                automatic budget (transparent, out-of-bounds and duplicate Gaussians go), as
                the pipeline ships it and as ``budget=None`` means everywhere in prosplat; an
                int a count, a float in (0, 1] a fraction of them; ``"all"`` keeps every
                Gaussian: the generator's N·h·w, view-major, in pixel order.
            refine_steps / refine_seconds: refine the kept Gaussians against the inputs
                (:func:`prosplat.pipeline.refine.refine`) for that many steps (0 runs none
                but still sets the SH degree refinement fits) or seconds (> 0); at most one,
                None for both: no refinement. Refinement fits the full-size ``images`` and
                starts from the one-pass Gaussians, the depth sweep's scene-wide factor
                included (BENCHMARKS.md, "Refinement from the one-pass Gaussians").
            refine_options: :class:`~prosplat.pipeline.refine.RefineOptions` (the measured
                defaults when None); ``seed``: the order refinement visits the views in;
                ``progress(step, total, loss)`` and ``cancel()``: as in ``refine``.
            generator_height: the generator runs at most this many pixels high (None: the
                weights' :attr:`trained_size`; 0: the inputs' own size). Larger inputs are
                matched at that height, and with :attr:`full_res_gaussians` (the default for
                prosplat generators) the Gaussians are still placed at the inputs' size, up to
                :data:`MAX_GAUSSIAN_SCALE` times that height; otherwise they come at that
                height. Why: a generator matches best at the size it was trained at, while
                its Gaussians gain from the full-size pixels and render at any size
                (BENCHMARKS.md, "Gaussians at the inputs' size", "The pipeline now").
            depth_scale: the depth sweep (:attr:`depth_sweep`) also picks a scene-wide depth
                factor (:func:`prosplat.pipeline.depth_sweep.scale_search`); with a budget it
                is searched on the budget's survivors and applied after the budget, so the
                same Gaussians are kept with it and without it. False leaves it out.
            anchors: sparse 3D points the inputs observe
                (:class:`~prosplat.geometry.anchors.DepthAnchors`, e.g. ``depth_range(...).anchors``):
                each view's depth is scaled to agree with its points before the depth sweep
                (:func:`~prosplat.geometry.anchors.anchor_depths`; the fits land in
                ``anchor_fits``). None: the generator's depth as it comes.
            grad: keep the generator's autograd graph in ``gaussians`` and ``depths``; only
                with ``budget="all"`` and no refinement (pruning and refinement detach). For
                the network's raw output use :meth:`run_generator`.

        Returns:
            :class:`~prosplat.pipeline.reconstruction.Reconstruction`: the Gaussians, the
            cameras and depth maps they belong to (the generator's size), the view index per
            Gaussian, the budget's and refinement's statistics and the seconds of each part.

        Raises:
            ValueError: images not [N,3,H,W] floats in [0, 1] or with NaN, a camera per image
                missing or of another size, cameras at one place with no near/far, a bad
                budget, both or bad refine_steps / refine_seconds (checked before the
                generator runs), or ``grad`` with a budget or refinement.
        """
        refining = refine_steps is not None or refine_seconds is not None
        if refining:  # before the generator runs, so a bad call costs nothing
            check_refine_inputs(images, list(cameras), "reconstruct")
            check_budget(refine_steps, refine_seconds)
        if isinstance(budget, str) and budget != "all":
            raise ValueError(
                f"budget must be None (automatic), a count, a fraction or 'all', got {budget!r}"
            )
        if grad and (budget != "all" or refining):
            raise ValueError(
                "grad=True keeps the generator's autograd graph, which the budget and refinement "
                "drop: pass budget='all' without refinement, or use run_generator()"
            )
        if anchors is not None and anchors.observed is not None:
            if len(anchors.observed) != len(cameras):
                raise ValueError(
                    f"anchors observed by {len(anchors.observed)} views, but {len(cameras)} "
                    "cameras: take anchors.views(indices) for a subset of the inputs"
                )
        fits: list[AnchorFit] = []
        if budget == "all":
            rec = self._unpruned(
                images, cameras, near, far, generator_height, grad, depth_scale, anchors, fits
            )
        else:
            rec = self._pruned(
                images, cameras, near, far, budget, generator_height, depth_scale, anchors, fits
            )
        rec.anchor_fits = fits
        return self._refined(rec, images, cameras, refine_steps, refine_seconds, refine_options,
                             seed, progress, cancel) if refining else rec  # fmt: skip

    def run_generator(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        *,
        sweep: bool = False,
        grad: bool = False,
    ) -> GeneratorOutput:
        """The generator network alone on ``images [N,3,H,W]`` as given (no resizing, no
        budget, no refinement), in eval mode: its raw
        :class:`~prosplat.generator.GeneratorOutput` (per-pixel Gaussians, depths, confidence,
        depth logits), with the autograd graph when ``grad``. For training, tests and
        measurements of the network itself; :meth:`reconstruct` is the pipeline.

        near/far default to :func:`~prosplat.geometry.rig.near_far_from_cameras`.
        ``sweep``: the model's :attr:`depth_sweep` (scene-wide factor included) runs after the
        network, as ``reconstruct(..., budget="all", generator_height=0)`` runs it, with its
        output left unchecked (a NaN stays visible here, where building Gaussians would
        raise). Images that are not float or not in [0, 1] raise ``ValueError`` naming the
        fix (:func:`prosplat.core.image_io.check_images`)."""
        cameras = list(cameras)
        out = self._forward(images, cameras, near, far, grad=grad)
        return self._swept(out, images, cameras, depth_scale=True) if sweep else out

    def _forward(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None,
        far: float | None,
        *,
        grad: bool = False,
        match_size: tuple[int, int] | None = None,
    ) -> GeneratorOutput:
        """The generator (eval mode) on one scene, no autograd graph unless ``grad``.
        ``match_size`` (H, W): the generator matches at that size and places its Gaussians at
        the images' (:meth:`_generate`)."""
        imgs, K, w2c, near, far = self._inputs(images, cameras, near, far)
        # switched only when needed: .train() walks ~500 modules in Python, 13 ms of a 64-px
        # reconstruction's ~0.25 s when done twice per call
        was_training = self.generator.training
        if was_training:
            self.generator.eval()
        extra = {} if match_size is None else {"match_size": match_size}
        try:
            with torch.set_grad_enabled(grad):
                return self.generator(imgs, K, w2c, near, far, **extra)
        finally:
            if was_training:
                self.generator.train()

    def _generator_views(
        self, images: Tensor, cameras: Sequence[Camera], height: int | None = None
    ) -> tuple[Tensor, list[Camera]]:
        """The inputs as the generator should see them: resized (antialiased) to ``height``
        px when that is below their own height, the width keeping the aspect (a multiple of
        32), with matching cameras; unchanged otherwise, unless a side is not a multiple of 32
        (the network's stride): then they go down to the multiple below. ``height`` None: the model's
        :attr:`trained_size`; 0: the inputs' own size.

        Why: a generator works best at the size it was trained at (``TRAINED_SIZE`` for the
        shipped weights), and its Gaussians do not depend on the size they were made at, so
        they render at any camera's size and refine against the full-size inputs. The shipped
        generator run at 64 px and rendered at 128 px scores 15.93 dB on the test scenes
        against 15.32 dB when it runs at 128 px, and its 4x fewer Gaussians refine in half the
        time and better (BENCHMARKS.md, "The pipeline now").
        """
        cameras = list(cameras)
        h, w = images.shape[-2:]
        height = self.trained_size if height is None else height
        height = h if not height else min(int(height), h)
        height = max(32, height - height % 32)  # the network's stride
        if (height, resized_width(w, h, height)) == (h, w):
            return images, cameras
        return resize_views(images, cameras, height)

    def _generate(
        self, images: Tensor, cameras, near, far, height, grad: bool, depth_scale: bool,
        anchors: DepthAnchors | None = None, fits: list | None = None,
    ) -> tuple[GeneratorOutput, Tensor, list[Camera]]:  # fmt: skip
        """The generator as the pipeline runs it on inputs larger than ``height`` (None:
        :attr:`trained_size`; 0: the inputs' size): its output, the images at the size of its
        depth maps and the cameras its pixel-aligned Gaussians and depth maps belong to.

        With :attr:`full_res_gaussians` (the default; prosplat generators only) the network
        runs at ``height`` up to its depth refiner, whose depth and features are upsampled to
        the inputs' size, where the adapter places one Gaussian per input pixel with that
        pixel's colour (at most :data:`MAX_GAUSSIAN_SCALE` times ``height``: inputs that are
        larger, or not multiples of 32, are resized first; refinement still fits the inputs
        as given). Otherwise the inputs are resized to ``height``
        (:meth:`_generator_views`) and the Gaussians come at that size. Why: matching is what
        does not carry to a size the weights were not trained at, while the Gaussians' colour
        and footprint gain from the full-size pixels (BENCHMARKS.md, "Gaussians at the inputs'
        size"). ``depth_scale``: the depth sweep also picks a scene-wide depth factor
        (:func:`prosplat.pipeline.depth_sweep.scale_search`); False leaves the local sweep
        alone (:meth:`_pruned` applies the factor itself, after the budget). ``anchors``:
        each view's depth scaled to its points before the sweep (:meth:`_anchored`), the
        fits appended to ``fits``.
        """
        cameras = list(cameras)
        height = self.trained_size if height is None else height
        h = images.shape[-2]
        if not (self.full_res_gaussians and isinstance(self.generator, Generator)) or (
            not height or height >= h
        ):
            gen_images, gen_cameras = self._generator_views(images, cameras, height)
            out = self._forward(gen_images, gen_cameras, near, far, grad=grad)
            out = self._anchored(out, gen_cameras, anchors, fits)
            out = self._swept(out, gen_images, gen_cameras, depth_scale)
            return self._edged(out, gen_cameras, 1.0), gen_images, gen_cameras
        top = int(min(h, self.max_gaussian_scale * int(height))) // 32 * 32
        images, cameras = resize_views(images, cameras, top)  # unchanged when already there
        match = (int(height), resized_width(images.shape[-1], images.shape[-2], int(height)))
        out = self._forward(images, cameras, near, far, grad=grad, match_size=match)
        out = self._anchored(out, cameras, anchors, fits)
        out = self._swept(out, images, cameras, depth_scale)
        return self._edged(out, cameras, top / int(height)), images, cameras

    def _anchored(
        self, out: GeneratorOutput, cameras: list[Camera], anchors: DepthAnchors | None,
        fits: list | None,
    ) -> GeneratorOutput:  # fmt: skip
        """``out`` with each view's depth scaled to agree with the ``anchors`` it observes, its
        Gaussians slid along their rays to match (unchanged without anchors)."""
        if anchors is None:
            return out
        new, view_fits = anchor_depths(out.depths[0].detach(), cameras, anchors.points,
                                       anchors.observed)  # fmt: skip
        if fits is not None:
            fits.extend(view_fits)
        if not any(f.used for f in view_fits):
            return out
        return slide_along_rays(out, cameras, new)

    def _edged(self, out: GeneratorOutput, cameras: list[Camera], scale: float) -> GeneratorOutput:
        """``out`` with its depth edges resolved (:attr:`depth_edges`; unchanged when None);
        ``scale``: the Gaussians' size over the matching size."""
        if self.depth_edges is None or not isinstance(self.generator, Generator):
            return out
        return resolve_output(out, cameras, self.depth_edges, scale)

    def _swept(
        self, out: GeneratorOutput, images: Tensor, cameras: list[Camera], depth_scale: bool
    ) -> GeneratorOutput:
        """``out`` after :attr:`depth_sweep` (unchanged when it is None), its scene-wide
        factor left out unless ``depth_scale``."""
        if self.depth_sweep is None:
            return out
        options = self.depth_sweep
        if not depth_scale:
            options = replace(options, scale_candidates=0)
        return snap_output(out, images.to(self.device), cameras, options)

    def _unpruned(
        self, images: Tensor, cameras, near, far, height, grad: bool, depth_scale: bool,
        anchors: DepthAnchors | None = None, fits: list | None = None,
    ) -> Reconstruction:  # fmt: skip
        """:meth:`reconstruct` with ``budget="all"``: every Gaussian the generator places."""
        t0 = time.perf_counter()
        out, _, gen_cameras = self._generate(
            images, cameras, near, far, height, grad, depth_scale, anchors, fits
        )
        g = out.gaussians(0)
        depths = out.depths[0]  # [V,h,w]
        v, h, w = depths.shape
        view_index = torch.arange(v, device=g.device).repeat_interleave(h * w)  # [N]
        stats = {"input": len(g), "transparent": 0, "out_of_bounds": 0, "duplicate": 0,
                 "over_budget": 0, "kept": len(g)}  # fmt: skip
        t1 = time.perf_counter()
        g, survive, stats = self._cross_checked(g, view_index, depths, gen_cameras, stats)
        if survive is not None:
            view_index = view_index[survive]
        checked_s = time.perf_counter() - t1 if self.cross_view is not None else 0.0
        timings = {"generator": t1 - t0, "prune": checked_s, "refine": 0.0}
        return Reconstruction(g, gen_cameras, depths, view_index, stats, None, timings)

    def _pruned(
        self, images: Tensor, cameras, near, far, budget, height, depth_scale: bool,
        anchors: DepthAnchors | None = None, fits: list | None = None,
    ) -> Reconstruction:  # fmt: skip
        """:meth:`reconstruct` up to the budget: the generator as the pipeline runs it, its
        pixel-aligned Gaussians pruned to ``budget`` with the cameras at the size it ran at,
        so no caller can pair the generator's depth maps with cameras of another size. The
        depth sweep's scene-wide factor (``depth_scale``) is searched on the budget's
        survivors and applied after the budget, so the same Gaussians are kept with it and
        without it (refined and one-pass reconstructions keep one count)."""
        t0 = time.perf_counter()
        out, gen_images, gen_cameras = self._generate(
            images, cameras, near, far, height, False, False, anchors, fits
        )
        t1 = time.perf_counter()
        depths = out.depths[0].detach()
        g, keep, stats = prune_pixel_aligned(
            out.gaussians(0).detach(), depths, gen_cameras, budget=budget
        )
        v, h, w = depths.shape
        view_index = torch.arange(v, device=keep.device).repeat_interleave(h * w)[keep]
        t2 = time.perf_counter()
        if depth_scale and self.depth_sweep is not None and self.depth_sweep.searches_scale(v):
            factor, _ = scale_search(
                out, gen_images.to(self.device), gen_cameras, self.depth_sweep, keep=keep
            )
            if factor != 1.0:
                g = slide_gaussians(g, view_index, gen_cameras, factor)
                depths = depths * factor
        # the search is part of the depth sweep: its seconds count as the generator's
        generator_s = (t1 - t0) + (time.perf_counter() - t2)
        t3 = time.perf_counter()
        g, survive, stats = self._cross_checked(g, view_index, depths, gen_cameras, stats)
        if survive is not None:  # dropped (fade 0): the pixel mask follows, for the merge
            view_index = view_index[survive]
            keep = keep.clone()
            keep[torch.nonzero(keep).squeeze(1)[~survive]] = False
        prune_s = (t2 - t1) + (time.perf_counter() - t3)
        if self.merge_flat is not None and self._placed_scale(gen_cameras, height) > (
            self.merge_flat.above_scale
        ):
            t3 = time.perf_counter()
            g, view_index, merged = merge_flat(g, keep, depths, gen_cameras, self.merge_flat)
            stats = {**stats, "merged": merged["before"] - merged["after"], "kept": len(g)}
            prune_s += time.perf_counter() - t3
        timings = {"generator": generator_s, "prune": prune_s, "refine": 0.0}
        return Reconstruction(g, gen_cameras, depths, view_index, stats, None, timings)

    def _cross_checked(
        self, g: Gaussians, view_index: Tensor, depths: Tensor, cameras: list[Camera], stats: dict
    ) -> tuple[Gaussians, Tensor | None, dict]:
        """``g`` [N] faded (or dropped) where other input views saw through it
        (:attr:`cross_view`, :func:`~prosplat.geometry.consistency.fade_contradicted`) on the
        generator's own depth maps ``depths`` [V,h,w] at ``cameras``, with the [N] mask of the
        Gaussians that stay when fading drops (``fade=0``; else None); unchanged when off.
        ``stats`` gains ``faded`` and the new ``kept``."""
        if self.cross_view is None:
            return g, None, stats
        check = cross_view_check(
            depths.detach(), cameras, self.cross_view.tau, means=g.means, view_index=view_index
        )
        faded, n_faded = fade_contradicted(g, check, self.cross_view.fade)
        survive = None
        if self.cross_view.fade == 0:
            survive = check.contradictions.to(view_index.device) == 0  # [N]
        return faded, survive, {**stats, "faded": n_faded, "kept": len(faded)}

    def _placed_scale(self, gen_cameras: list[Camera], height: int | None) -> float:
        """How many times the matching height (``height``; None: :attr:`trained_size`; 0:
        the inputs') the Gaussians were placed at: ``gen_cameras``' height over it, 1 when
        the generator matched at the Gaussians' own size."""
        height = self.trained_size if height is None else height
        if not height:
            return 1.0
        return max(1.0, gen_cameras[0].height / int(height))

    def _refined(
        self, rec: Reconstruction, images: Tensor, cameras, steps, seconds, options, seed,
        progress, cancel,
    ) -> Reconstruction:  # fmt: skip
        """``rec`` with its Gaussians refined against the full-size ``images``
        (:func:`prosplat.pipeline.refine.refine`): the generator's depth feeds the depth term
        when its maps are the images' size (else the term is off), its view index the
        cross-view term; refinement keeps the count and order of the Gaussians."""
        g = rec.gaussians
        t0 = time.perf_counter()
        result = refine(
            g,
            images.to(g.means.device),
            list(cameras),
            steps=steps,
            seconds=seconds,
            seed=seed,
            progress=progress,
            cancel=cancel,
            depths=rec.depths_for(images),
            view_index=rec.view_index,
            options=options,
        )
        timings = {**rec.timings, "refine": time.perf_counter() - t0}
        return replace(rec, gaussians=result.gaussians, refine_stats=result.stats, timings=timings)

    def render(
        self,
        gaussians: Gaussians | Reconstruction,
        camera: Camera,
        images: Tensor | None = None,
        cameras: Sequence[Camera] | None = None,
        enhance: bool = True,
        **view_options,
    ) -> EnhancedView:
        """Render ``camera`` and enhance it with the improvement model:
        :func:`prosplat.pipeline.enhance.render_view` with :attr:`improver` (none with
        ``enhance=False``: the raw render, ``image is raw``, ``reference`` None).

        MORI picks the reference among the input ``cameras``; ``images [N,3,H,W]`` are their
        images. ``gaussians`` may be a :class:`Reconstruction`: its Gaussians render, and its
        cameras stand in for ``cameras`` when those are not given (resized to ``images``'
        size when the generator ran smaller).

        ``view_options`` are ``render_view``'s keyword options, documented there:
        ``reference_method`` ("paper" or "overlap"), ``background``, ``dtype``
        (``torch.bfloat16`` runs stage 2 under autocast), ``options``
        (:class:`~prosplat.pipeline.enhance.EnhanceOptions`: working size and guard; a guarded
        view returns the raw render as ``image`` and the reason in ``view.guard``),
        ``fill_holes``, ``fill_enhanced``, ``splat_scale``, ``max_splat_radius`` and
        ``other_views_opacity``.

        Raises:
            ValueError: ``enhance`` without an improvement model loaded (train one with
                ``prosplat train improve`` or pass ``improve=`` to :meth:`from_pretrained`).
            TypeError: a keyword ``render_view`` does not take.
        """
        if isinstance(gaussians, Reconstruction):
            if cameras is None:
                cameras = gaussians.cameras
                if images is not None and (cameras[0].height, cameras[0].width) != tuple(
                    images.shape[-2:]
                ):
                    cameras = [c.resized(images.shape[-1], images.shape[-2]) for c in cameras]
            gaussians = gaussians.gaussians
        if images is not None:
            check_images(images, "images")
        if enhance and self.improver is None:
            raise ValueError(
                "no improvement model is loaded (model.improver is None); load one with "
                "ProSplat.from_pretrained(improve=PATH) or call render(..., enhance=False)"
            )
        return render_view(
            gaussians, camera, images, cameras, self.improver if enhance else None, **view_options
        )

    def distill(
        self,
        gaussians: Gaussians,
        view_cameras: Sequence[Camera],
        images: Tensor,
        cameras: Sequence[Camera],
        *,
        steps: int | None = None,
        seconds: float | None = None,
        progress=None,
        cancel=None,
        dtype: torch.dtype = torch.float32,
    ):
        """Gaussians that show every camera of ``view_cameras`` as the improvement model
        enhances it, consistently (:func:`prosplat.pipeline.distill.distill_enhanced`): each view is
        enhanced, then ``gaussians`` are refined against the inputs (``images [N,3,H,W]``,
        ``cameras``) and those views together for ``steps`` (default 800) or ``seconds``.
        Render the result's ``gaussians`` raw at the view cameras: frames of a camera path
        then agree with each other, which views enhanced one by one do not.

        Raises:
            ValueError: no improvement model loaded, no view cameras, or a view camera whose
                aspect ratio differs from the inputs'.
        """
        from prosplat.pipeline.distill import distill_enhanced

        check_images(images, "images")
        return distill_enhanced(
            gaussians, images, cameras, view_cameras, self.improver, steps=steps,
            seconds=seconds, progress=progress, cancel=cancel, dtype=dtype,
        )  # fmt: skip
