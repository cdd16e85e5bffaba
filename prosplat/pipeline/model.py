"""The user-facing entry point: posed images in, Gaussians out, enhanced views of any camera.

    >>> model = ProSplat.from_pretrained()            # shipped weights (or a path)
    >>> gaussians = model.reconstruct(images, cameras)  # images [N,3,H,W] in [0,1]
    >>> view = model.render(gaussians, camera, images, cameras)  # view.image: enhanced [3,H,W]

Checkpoints are safetensors files holding the generator's weights and, in the metadata, the
:class:`~prosplat.generator.GeneratorConfig` as JSON, so a file always rebuilds its own network.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.core.checkpoints import read_checkpoint, write_checkpoint
from prosplat.core.gaussians import Gaussians
from prosplat.core.image_io import check_images
from prosplat.generator import TINY, Generator, GeneratorConfig, GeneratorOutput
from prosplat.pipeline.enhance import (
    MAX_SPLAT_RADIUS,
    OTHER_VIEWS_OPACITY,
    EnhancedView,
    EnhanceOptions,
    render_view,
)

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

#: :meth:`ProSplat.generate` places Gaussians at most this many times the matching height
#: (256 px for the shipped weights): 2x is the measured case (BENCHMARKS.md, "Gaussians at
#: the inputs' size"), and a 1080p camera's inputs would otherwise make 2 M Gaussians a view
MAX_GAUSSIAN_SCALE = 2

#: near = NEAR_FACTOR · (smallest camera distance) · f / image size (see near_far_from_cameras)
NEAR_FACTOR = 0.5
#: far = FAR_FACTOR · max(largest camera distance, near), for rigs that do not converge
FAR_FACTOR = 100.0
#: converging rigs: near/far = these factors times the nearest/farthest camera's depth of the
#: point the optical axes meet at
CONVERGING_NEAR = 0.5
CONVERGING_FAR = 2.5
#: axes converge when that point is in front of every camera, inside its image, and no farther
#: than this many times the rig's largest baseline (nearly parallel axes meet far away)
CONVERGING_MAX_DEPTH = 20.0


def convergence_point(cameras: Sequence[Camera]) -> Tensor | None:
    """The point the cameras' optical axes meet at (least squares), or None when they do not
    converge: the point must lie in front of every camera and project inside its image, and
    be at most :data:`CONVERGING_MAX_DEPTH` times the largest baseline from every camera (axes
    that are nearly parallel, e.g. a forward-facing capture, meet far away or nowhere)."""
    centers = torch.stack([c.center.double().cpu() for c in cameras])  # [N,3]
    fwd = torch.stack([c.forward.double().cpu() for c in cameras])  # [N,3]
    eye = torch.eye(3, dtype=torch.float64)
    P = eye[None] - fwd[:, :, None] * fwd[:, None, :]  # [N,3,3] projectors off each axis
    A, rhs = P.sum(0), (P @ centers[:, :, None]).sum(0)[:, 0]
    if float(torch.linalg.eigvalsh(A)[0]) < 1e-9 * len(cameras):
        return None  # all axes parallel
    p = torch.linalg.solve(A, rhs)
    baseline = float(torch.cdist(centers, centers).max())
    for cam in cameras:
        c = cam.to(dtype=torch.float64)
        uv, z = c.project(p[None].to(c.K))
        u, v = float(uv[0, 0]), float(uv[0, 1])
        if not (0 < float(z[0]) <= CONVERGING_MAX_DEPTH * baseline):
            return None
        if not (0 <= u <= cam.width and 0 <= v <= cam.height):
            return None
    return p


def near_far_from_cameras(cameras: Sequence[Camera]) -> tuple[float, float]:
    """A depth range from the cameras alone (no triangulation, no scene content).

    *Converging rigs* (object-centric captures such as NeRF-synthetic scenes, whose optical
    axes meet in front of the cameras, see :func:`convergence_point`): the scene is around the
    point p the axes meet at, so ``near`` is :data:`CONVERGING_NEAR` times the smallest depth
    of p over the cameras and ``far`` :data:`CONVERGING_FAR` times the largest. A lego-like
    rig (radius 4, object radius 1.5) gets near 2, in front of the object's surface at 2.5,
    and far 10, past its back at 5.5.

    *Other rigs* (forward-facing, diverging): two cameras a baseline b apart see a point at
    depth z shifted by about ``f·b/z`` pixels; once that shift exceeds the image size S the
    point cannot be in both views, so matching can only find depths beyond ``b·f/S``.
    ``near`` is half of that for the closest camera pair, with ``f/S`` the smallest ``fx/W``
    or ``fy/H`` over the cameras. ``far`` is 100 times the rig's largest camera distance: the
    depth candidates are uniform in inverse depth, so a generous far costs only the few
    candidates between 0 and 1/far.

    Data with known bounds (Blender scenes, COLMAP points) should pass near/far instead.

    Raises:
        ValueError: fewer than two cameras, or two cameras at the same place (zero baseline,
            e.g. a pure rotation), where the cameras carry no depth scale.
    """
    if len(cameras) < 2:
        raise ValueError(
            f"near/far need at least two cameras to derive a depth range, got {len(cameras)}"
        )
    centers = torch.stack([c.center.double().cpu() for c in cameras])  # [N,3]
    dist = torch.cdist(centers, centers)  # [N,N]
    n = len(cameras)
    iu = torch.triu_indices(n, n, offset=1)
    pair = dist[iu[0], iu[1]]  # [N(N-1)/2]
    scale = max(1.0, float(centers.abs().max()))
    k = int(pair.argmin())
    if float(pair[k]) <= 1e-6 * scale:
        i, j = int(iu[0, k]), int(iu[1, k])
        raise ValueError(
            f"cameras {i} and {j} are at the same place (zero baseline, e.g. a pure rotation), so the "
            "cameras give no depth scale; pass near= and far= (scene units) explicitly"
        )
    p = convergence_point(cameras)
    if p is not None:
        depths = [float(c.world_to_camera(p[None].to(c.K))[0, 2]) for c in cameras]
        return CONVERGING_NEAR * min(depths), CONVERGING_FAR * max(depths)
    f_over_size = min(min(c.fx / c.width, c.fy / c.height) for c in cameras)
    near = NEAR_FACTOR * float(pair.min()) * f_over_size
    far = FAR_FACTOR * max(float(pair.max()), near)
    return near, far


def is_depthsplat_file(path: str | Path | None) -> bool:
    """Whether a generator file given as one path (the add-on's *Generator Weights*, the
    worker's ``weights``) goes to ``from_pretrained(generator=...)``: decided by the suffix,
    which costs nothing and needs no torch.load of a file that may be 1.4 GB."""
    return path is not None and Path(str(path)).suffix.lower() in DEPTHSPLAT_SUFFIXES


@dataclass
class PrunedReconstruction:
    """What :meth:`ProSplat.reconstruct_pruned` returns: the generator's Gaussians pruned to
    the budget, with ``depths [V,h,w]`` the generator's depth per input view and ``cameras``
    the inputs' cameras, both at the size the generator ran at; ``stats`` the pruning's counts
    (``input``, ``kept``, ...) and the seconds of each part."""

    gaussians: Gaussians
    depths: Tensor
    cameras: list[Camera]
    stats: dict
    generator_s: float
    prune_s: float
    view_index: Tensor | None = None  # [N] the input view that predicted each kept Gaussian

    def depths_for(self, images: Tensor) -> Tensor | None:
        """``depths`` when they match ``images [V,3,H,W]`` in size (refinement's depth term
        and MORI's occlusion test need maps at the images' size), else None."""
        return self.depths if self.depths.shape[-2:] == images.shape[-2:] else None


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
        #: the generator at most this high (:meth:`generator_views`)
        self.trained_size = trained_size
        #: place the Gaussians at the inputs' own size when the generator matches at a smaller
        #: one (:meth:`generate`); False: at the matching size, as before 2026-11-24
        self.full_res_gaussians = True
        #: a local plane sweep around the generator's depth (:mod:`prosplat.pipeline.depth_sweep`) moves
        #: its Gaussians to where the inputs match (:meth:`generate`); None: off
        self.depth_sweep = None
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
        from prosplat.pipeline.depth_sweep import DepthSweepOptions

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

    def reconstruct_full(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        *,
        grad: bool = False,
        match_size: tuple[int, int] | None = None,
    ) -> GeneratorOutput:
        """Run the generator (eval mode) on one scene: ``images [N,3,H,W]`` in [0,1] with one
        :class:`Camera` each. near/far default to :func:`near_far_from_cameras`. No autograd
        graph unless ``grad``. Images that are not float or not in [0, 1] (``uint8``, 0-255)
        raise ``ValueError`` naming the fix (:func:`prosplat.core.image_io.check_images`).
        ``match_size`` (H, W): the generator matches at that size and places its Gaussians at
        the images' (:meth:`generate`)."""
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

    def generate(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        height: int | None = None,
        *,
        grad: bool = False,
        depth_scale: bool = True,
    ) -> tuple[GeneratorOutput, list[Camera]]:
        """The generator as the pipeline runs it on inputs larger than ``height`` (None:
        :attr:`trained_size`; 0: the inputs' size): returns its output and the cameras its
        pixel-aligned Gaussians and depth maps belong to.

        With :attr:`full_res_gaussians` (the default; prosplat generators only) the network
        runs at ``height`` up to its depth refiner, whose depth and features are upsampled to
        the inputs' size, where the adapter places one Gaussian per input pixel with that
        pixel's colour (at most :data:`MAX_GAUSSIAN_SCALE` times ``height``: inputs that are
        larger, or not multiples of 32, are resized first; refinement still fits the inputs
        as given). Otherwise the inputs are resized to ``height``
        (:meth:`generator_views`) and the Gaussians come at that size. Why: matching is what
        does not carry to a size the weights were not trained at, while the Gaussians' colour
        and footprint gain from the full-size pixels (BENCHMARKS.md, "Gaussians at the inputs'
        size"). ``depth_scale``: the depth sweep also picks a scene-wide depth factor
        (:func:`prosplat.pipeline.depth_sweep.scale_search`); False leaves the local sweep alone, as
        refinement wants (:meth:`reconstruct_refined`).
        """
        out, _, gen_cameras = self._generate(images, cameras, near, far, height, grad, depth_scale)
        return out, gen_cameras

    def _generate(
        self, images: Tensor, cameras, near, far, height, grad: bool, depth_scale: bool
    ) -> tuple[GeneratorOutput, Tensor, list[Camera]]:
        """:meth:`generate`, also returning the images at the size of its depth maps."""
        cameras = list(cameras)
        height = self.trained_size if height is None else height
        h = images.shape[-2]
        if not (self.full_res_gaussians and isinstance(self.generator, Generator)) or (
            not height or height >= h
        ):
            gen_images, gen_cameras = self.generator_views(images, cameras, height)
            out = self.reconstruct_full(gen_images, gen_cameras, near, far, grad=grad)
            out = self._swept(out, gen_images, gen_cameras, depth_scale)
            return out, gen_images, gen_cameras
        from prosplat.data.scene import resize_views, resized_width

        top = min(h, MAX_GAUSSIAN_SCALE * int(height)) // 32 * 32
        images, cameras = resize_views(images, cameras, top)  # unchanged when already there
        match = (int(height), resized_width(images.shape[-1], images.shape[-2], int(height)))
        out = self.reconstruct_full(images, cameras, near, far, grad=grad, match_size=match)
        return self._swept(out, images, cameras, depth_scale), images, cameras

    def _swept(
        self, out: GeneratorOutput, images: Tensor, cameras: list[Camera], depth_scale: bool
    ) -> GeneratorOutput:
        """``out`` after :attr:`depth_sweep` (unchanged when it is None), its scene-wide
        factor left out unless ``depth_scale``."""
        if self.depth_sweep is None:
            return out
        from prosplat.pipeline.depth_sweep import snap_output

        options = self.depth_sweep
        if not depth_scale:
            options = replace(options, scale_candidates=0)
        return snap_output(out, images.to(self.device), cameras, options)

    def reconstruct(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        refine_steps: int = 0,
        refine_seconds: float | None = None,
        *,
        grad: bool = False,
        budget: int | float | None = None,
        refine_options=None,
        seed: int = 0,
        progress=None,
        cancel=None,
        generator_height: int | None = None,
    ) -> Gaussians:
        """Gaussians of one scene; see :meth:`reconstruct_full`.

        Without refinement (``refine_steps=0``, ``refine_seconds`` None or 0): the generator's
        N·H·W Gaussians, view-major, unpruned (prune with
        :func:`prosplat.geometry.budget.prune_pixel_aligned`). With ``refine_steps=N`` or
        ``refine_seconds=S`` (not both): :meth:`reconstruct_refined`'s Gaussians, pruned to
        ``budget`` (automatic when None) and then fitted to the inputs (no longer
        pixel-aligned, so prune before, never after). ``budget``, ``refine_options``, ``seed``,
        ``progress`` and ``cancel`` only matter with refinement. ``generator_height``: the
        generator runs at most this high (:meth:`generator_views`; None: :attr:`trained_size`,
        0: the inputs' size).
        """
        if not refine_steps and not refine_seconds:
            out, _ = self.generate(images, cameras, near, far, generator_height, grad=grad)
            return out.gaussians(0)
        return self.reconstruct_refined(
            images,
            cameras,
            near,
            far,
            steps=refine_steps or None,
            seconds=refine_seconds or None,
            budget=budget,
            options=refine_options,
            seed=seed,
            progress=progress,
            cancel=cancel,
            generator_height=generator_height,
        ).gaussians

    def generator_views(
        self, images: Tensor, cameras: Sequence[Camera], height: int | None = None
    ) -> tuple[Tensor, list[Camera]]:
        """The inputs as the generator should see them: resized (antialiased) to ``height``
        px when that is below their own height, the width keeping the aspect (a multiple of
        32), with matching cameras; unchanged otherwise. ``height`` None: the model's
        :attr:`trained_size`; 0: the inputs' own size.

        Why: a generator works best at the size it was trained at (``TRAINED_SIZE`` for the
        shipped weights), and its Gaussians do not depend on the size they were made at, so
        they render at any camera's size and refine against the full-size inputs. The shipped
        generator run at 64 px and rendered at 128 px scores 15.93 dB on the test scenes
        against 15.32 dB when it runs at 128 px, and its 4x fewer Gaussians refine in half the
        time and better (BENCHMARKS.md, "The pipeline now").
        """
        cameras = list(cameras)
        height = self.trained_size if height is None else height
        if not height or height >= images.shape[-2]:
            return images, cameras
        from prosplat.data.scene import resize_views

        return resize_views(images, cameras, int(height))

    def reconstruct_pruned(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        *,
        budget: int | float | None = None,
        generator_height: int | None = None,
        depth_scale: bool = True,
    ) -> PrunedReconstruction:
        """The generator as the pipeline runs it, then the Gaussian budget: the generator at
        most ``generator_height`` px high (:meth:`generator_views`; None: :attr:`trained_size`,
        0: the inputs' size), its pixel-aligned Gaussians pruned (``budget``: a count, a
        fraction, or None for the automatic budget) with the cameras at the size it ran at.
        Every caller that wants pruned Gaussians comes here, so none can pair the generator's
        depth maps with cameras of another size. ``depth_scale``: as in :meth:`generate`
        (pass False for Gaussians that will be refined); here the factor is searched on the
        budget's survivors and applied after the budget, so the same Gaussians are kept with
        it and without it."""
        from prosplat.geometry.budget import prune_pixel_aligned

        t0 = time.perf_counter()
        # the scene-wide factor is applied after the budget, so the same Gaussians survive
        # with it and without it (refined and one-pass reconstructions keep one count)
        out, gen_images, gen_cameras = self._generate(
            images, cameras, near, far, generator_height, grad=False, depth_scale=False
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
            from prosplat.pipeline.depth_sweep import scale_search, slide_gaussians

            factor, _ = scale_search(
                out, gen_images.to(self.device), gen_cameras, self.depth_sweep, keep=keep
            )
            if factor != 1.0:
                g = slide_gaussians(g, view_index, gen_cameras, factor)
                depths = depths * factor
        # the search is part of the depth sweep: its seconds count as the generator's
        generator_s = (t1 - t0) + (time.perf_counter() - t2)
        return PrunedReconstruction(g, depths, gen_cameras, stats, generator_s, t2 - t1,
                                    view_index)  # fmt: skip

    def reconstruct_refined(
        self,
        images: Tensor,
        cameras: Sequence[Camera],
        near: float | None = None,
        far: float | None = None,
        *,
        steps: int | None = None,
        seconds: float | None = None,
        budget: int | float | None = None,
        options=None,
        seed: int = 0,
        progress=None,
        cancel=None,
        generator_height: int | None = None,
    ):
        """Generator, Gaussian budget, then :func:`prosplat.pipeline.refine.refine` against the inputs.

        The generator's Gaussians are pruned first (``budget``: a count, a fraction, or None
        for the automatic budget), so refinement fits only Gaussians that will be kept and
        keeps their count; the generator's per-view depth feeds the optional depth term.
        Exactly one of ``steps`` / ``seconds``; ``progress(step, total, loss)`` and
        ``cancel()`` as in :func:`~prosplat.pipeline.refine.refine`. ``generator_height``: the generator
        runs at most this high (:meth:`generator_views`; None: :attr:`trained_size`, 0: the
        inputs' size) and refinement fits the full-size ``images``; the depth term is then off
        (its maps are the generator's size). Refinement starts from the one-pass Gaussians,
        the depth sweep's scene-wide factor included, so 0 steps is the one-pass scene
        (BENCHMARKS.md, "Refinement from the one-pass Gaussians").

        Returns:
            :class:`prosplat.pipeline.refine.RefineResult` (``gaussians``, ``stats``); ``stats`` also
            carries ``generator_s`` and ``prune_s`` (seconds) and ``pruned_from`` (count).
        """
        from prosplat.pipeline.refine import check_budget, check_images, refine

        check_images(images, list(cameras), "reconstruct")
        check_budget(steps, seconds)  # before the generator runs
        cameras = list(cameras)
        pruned = self.reconstruct_pruned(
            images, cameras, near, far, budget=budget, generator_height=generator_height
        )
        g = pruned.gaussians
        result = refine(
            g,
            images.to(g.means.device),
            cameras,
            steps=steps,
            seconds=seconds,
            seed=seed,
            progress=progress,
            cancel=cancel,
            depths=pruned.depths_for(images),
            view_index=pruned.view_index,
            options=options,
        )
        result.stats.generator_s = pruned.generator_s
        result.stats.prune_s = pruned.prune_s
        result.stats.pruned_from = int(pruned.stats["input"])
        return result

    def render(
        self,
        gaussians: Gaussians,
        camera: Camera,
        images: Tensor | None = None,
        cameras: Sequence[Camera] | None = None,
        enhance: bool = True,
        *,
        reference_method: str = "paper",
        background: Tensor | None = None,
        dtype: torch.dtype = torch.float32,
        options: EnhanceOptions | None = None,
        fill_holes: bool = False,
        fill_enhanced: bool = True,
        splat_scale: float = 1.0,
        max_splat_radius: float | None = MAX_SPLAT_RADIUS,
        other_views_opacity: float = OTHER_VIEWS_OPACITY,
    ) -> EnhancedView:
        """Render ``camera`` and enhance it with the improvement model.

        MORI picks the reference among the input ``cameras`` (``reference_method`` "paper" or
        "overlap"); ``images [N,3,H,W]`` are their images. ``enhance=False`` returns the raw
        render (``image is raw``, ``reference`` None). ``dtype=torch.bfloat16`` runs stage 2
        under autocast. ``options`` (:class:`~prosplat.pipeline.enhance.EnhanceOptions`) sets the
        working size and the guard: a guarded view returns the raw render as ``image`` and the
        reason in ``view.guard``. ``fill_holes``: a raw ``image`` (``enhance=False`` or
        guarded) has the holes no input saw filled from its own colours instead of black
        (:mod:`prosplat.render.hole_fill`; +3.1 / +3.5 / +4.1 dB at 64 / 128 / 256 px on the
        test scenes); an enhanced one is blended with the fill by the render's alpha unless
        ``fill_enhanced=False``, which keeps the fill to raw and guarded views.
        ``splat_scale``: the Gaussians' scales multiplied by it for this render
        (:data:`prosplat.pipeline.enhance.SPLAT_SCALE` suits the generator's unrefined Gaussians in a
        filled raw view; refined ones, and views the shipped stage 2 enhances, are best left at
        1). ``max_splat_radius``: a filled or enhanced view leaves out the splats this camera
        would draw wider than that fraction of its shorter side
        (:func:`prosplat.pipeline.enhance.oversized_splats`; None draws all; a raw view on black always
        draws all). ``other_views_opacity``: where the input views' Gaussians overlap, the
        colour favours the input MORI picks for ``camera``, the others drawn at up to this
        fraction of their opacity, less the farther they are from ``camera``
        (:func:`prosplat.pipeline.enhance.view_weights`; needs ``cameras`` and Gaussians that know
        their view, as :meth:`reconstruct` makes them;
        :data:`prosplat.pipeline.enhance.OTHER_VIEWS_OPACITY`; 1: off).

        Raises:
            ValueError: ``enhance`` without an improvement model loaded (train one with
                ``prosplat train improve`` or pass ``improve=`` to :meth:`from_pretrained`).
        """
        if images is not None:
            check_images(images, "images")
        if enhance and self.improver is None:
            raise ValueError(
                "no improvement model is loaded (model.improver is None); load one with "
                "ProSplat.from_pretrained(improve=PATH) or call render(..., enhance=False)"
            )
        return render_view(
            gaussians,
            camera,
            images,
            cameras,
            self.improver if enhance else None,
            reference_method=reference_method,
            background=background,
            dtype=dtype,
            options=options,
            fill_holes=fill_holes,
            fill_enhanced=fill_enhanced,
            splat_scale=splat_scale,
            max_splat_radius=max_splat_radius,
            other_views_opacity=other_views_opacity,
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
