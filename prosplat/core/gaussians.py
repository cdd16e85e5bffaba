"""A set of 3D Gaussians in the 3DGS parameterisation.

Stored in activated form (positive scales, opacities in [0, 1]) so that what a user reads is
what is rendered; the PLY file (``prosplat.core.ply``) holds the logit/log form that other splat
tools expect. Colour is ``SH · basis + 0.5`` clamped at 0 (the 3DGS convention), so an
``sh[:, 0]`` of ``(rgb - 0.5) / C0`` gives the colour ``rgb`` from every direction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

SH_C0 = 0.28209479177387814  # Y_0^0 = 1 / (2 sqrt(pi))


def rgb_to_sh0(rgb: Tensor) -> Tensor:
    """[..., 3] colour in [0, 1] -> [..., 3] degree-0 SH coefficient giving that colour."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0: Tensor) -> Tensor:
    """Inverse of :func:`rgb_to_sh0` (without the clamp)."""
    return sh0 * SH_C0 + 0.5


@dataclass
class Gaussians:
    """N anisotropic 3D Gaussians.

    Attributes:
        means: [N, 3] centres in world coordinates (scene units).
        quats: [N, 4] rotations as quaternions (w, x, y, z); need not be unit length, not zero.
        scales: [N, 3] standard deviations along the rotated axes, >= 0.
        opacities: [N] in [0, 1].
        sh: [N, K, 3] spherical-harmonic colour coefficients, K = (degree + 1)^2, degree 0-3.
        views: [N] integer, the input view that predicted each Gaussian (its index in the
            reconstruction's input cameras), or None when unknown (a PLY from elsewhere, an
            optimised scene). Subsets, copies and refinement keep it; views of a target use
            it to favour the input nearest that target where the views overlap
            (:func:`prosplat.pipeline.enhance.render_view`).
    """

    means: Tensor
    quats: Tensor
    scales: Tensor
    opacities: Tensor
    sh: Tensor
    views: Tensor | None = None

    #: the float parameters (every field but ``views``)
    PARAMS = ("means", "quats", "scales", "opacities", "sh")

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the field for wrong shapes, NaN/Inf, or out-of-range values."""
        means_ok = isinstance(self.means, Tensor) and self.means.ndim >= 1
        n = self.means.shape[0] if means_ok else -1  # a non-tensor fails the check below
        expected = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,)}
        for name, shape in expected.items():
            value = getattr(self, name)
            if not isinstance(value, Tensor):
                raise ValueError(
                    f"Gaussians.{name} must be a torch.Tensor, got {type(value).__name__}"
                )
            if tuple(value.shape) != shape:
                raise ValueError(
                    f"Gaussians.{name} must have shape {list(shape)} (N={n} from means), got {list(value.shape)}"
                )
        if (
            not isinstance(self.sh, Tensor)
            or self.sh.ndim != 3
            or self.sh.shape[0] != n
            or self.sh.shape[2] != 3
        ):
            shape = list(self.sh.shape) if isinstance(self.sh, Tensor) else type(self.sh).__name__
            raise ValueError(f"Gaussians.sh must have shape [N={n}, K, 3], got {shape}")
        k = self.sh.shape[1]
        if k not in (1, 4, 9, 16):
            raise ValueError(
                f"Gaussians.sh has K={k} coefficients; K must be (degree+1)^2 for degree 0-3"
            )
        self._validate_views(n)
        for name in self.PARAMS:
            value = getattr(self, name)
            if not value.is_floating_point():
                raise ValueError(
                    f"Gaussians.{name} must be a floating-point tensor, got {value.dtype}"
                )
            # One reduction first (a sum is finite iff every term is, barring overflow);
            # the element-wise test runs only when it is not. validate() runs per render.
            if (
                value.numel()
                and not torch.isfinite(value.detach().sum())
                and not torch.isfinite(value).all()
            ):
                bad = int((~torch.isfinite(value)).reshape(n, -1).any(dim=1).sum()) if n > 0 else 0
                raise ValueError(f"Gaussians.{name} contains NaN or Inf in {bad} of {n} Gaussians")
        if n and self.scales.detach().min() < 0:
            raise ValueError(
                f"Gaussians.scales must be >= 0 (they are standard deviations, not log-scales); "
                f"{int((self.scales < 0).any(dim=1).sum())} Gaussians have a negative scale"
            )
        lo, hi = torch.aminmax(self.opacities.detach()) if n else (0, 0)
        if lo < 0 or hi > 1:
            raise ValueError("Gaussians.opacities must lie in [0, 1] (activated, not logits)")
        if n and self.quats.detach().abs().amax(dim=1).min() == 0:
            raise ValueError(
                "Gaussians.quats has zero-length quaternions; use (1, 0, 0, 0) for no rotation"
            )

    def _validate_views(self, n: int) -> None:
        v = self.views
        if v is None:
            return
        if not isinstance(v, Tensor) or tuple(v.shape) != (n,):
            shape = list(v.shape) if isinstance(v, Tensor) else type(v).__name__
            raise ValueError(
                f"Gaussians.views must be None or an integer [N={n}] tensor, got {shape}"
            )
        if v.is_floating_point() or v.is_complex() or v.dtype == torch.bool:
            raise ValueError(f"Gaussians.views must be an integer tensor, got {v.dtype}")
        if n and int(v.min()) < 0:
            raise ValueError("Gaussians.views must be >= 0 (indices of input views)")

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def trusted(
        cls,
        means: Tensor,
        quats: Tensor,
        scales: Tensor,
        opacities: Tensor,
        sh: Tensor,
        views: Tensor | None = None,
    ) -> Gaussians:
        """Gaussians from tensors that are valid by construction, without :meth:`validate`.

        For inner loops only: a subset of valid Gaussians, or parameters through their
        activations (``exp`` scales, ``sigmoid`` opacities). Validation reads every value
        (3.5 ms for 60,000 Gaussians); a refinement step built and checked the same
        Gaussians up to four times (skipping it made a step 1.03-1.04x faster, BENCHMARKS
        "Refinement: dropping Gaussians"). Anything from outside (a file, a user, a
        network) goes through the checked constructor, and ``render`` checks by default.
        """
        g = cls.__new__(cls)
        g.means, g.quats, g.scales, g.opacities, g.sh = means, quats, scales, opacities, sh
        g.views = views
        return g

    def with_views(self, views: Tensor | None) -> Gaussians:
        """The same Gaussians with ``views`` [N] (the input view of each; None: unknown)."""
        return Gaussians(self.means, self.quats, self.scales, self.opacities, self.sh, views)

    @classmethod
    def empty(
        cls, sh_degree: int = 0, dtype: torch.dtype = torch.float32, device=None
    ) -> Gaussians:
        k = (sh_degree + 1) ** 2
        z = lambda *s: torch.zeros(*s, dtype=dtype, device=device)  # noqa: E731
        return cls(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, k, 3))

    @classmethod
    def from_colors(
        cls,
        means: Tensor,
        colors: Tensor,
        scales: Tensor,
        opacities: Tensor,
        quats: Tensor | None = None,
        sh_degree: int = 0,
    ) -> Gaussians:
        """Gaussians with view-independent colours ``colors [N,3]`` in [0, 1]."""
        n = means.shape[0]
        sh = torch.zeros(n, (sh_degree + 1) ** 2, 3, dtype=means.dtype, device=means.device)
        sh[:, 0] = rgb_to_sh0(colors)
        if quats is None:
            quats = torch.zeros(n, 4, dtype=means.dtype, device=means.device)
            quats[:, 0] = 1
        return cls(means, quats, scales, opacities, sh)

    @staticmethod
    def cat(parts: Sequence[Gaussians]) -> Gaussians:
        """Concatenate sets; SH are zero-padded to the highest degree among them. ``views``
        are kept when every part has them, else None."""
        if not parts:
            raise ValueError("Gaussians.cat needs at least one set")
        k = max(p.sh.shape[1] for p in parts)
        sh = [torch.nn.functional.pad(p.sh, (0, 0, 0, k - p.sh.shape[1])) for p in parts]
        views = None
        if all(p.views is not None for p in parts):
            views = torch.cat([p.views for p in parts])
        return Gaussians(
            torch.cat([p.means for p in parts]),
            torch.cat([p.quats for p in parts]),
            torch.cat([p.scales for p in parts]),
            torch.cat([p.opacities for p in parts]),
            torch.cat(sh),
            views,
        )

    # ---- access -------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.means.shape[0]

    def __getitem__(self, index) -> Gaussians:
        """A subset by slice, integer indices or boolean mask over the N Gaussians."""
        if isinstance(index, Tensor) and index.ndim == 0 and index.dtype != torch.bool:
            index = int(index)  # a 0-d index tensor (e.g. from argmax) is one Gaussian
        if isinstance(index, int):
            if not -len(self) <= index < len(self):  # a slice would silently give an empty set
                raise IndexError(f"Gaussian index {index} out of range for {len(self)} Gaussians")
            index = slice(index, index + 1 if index != -1 else None)
        parts = [getattr(self, name)[index] for name in self.PARAMS]
        views = None if self.views is None else self.views[index]
        if parts[0].ndim == 2:  # a subset of valid Gaussians is valid: no second read of them
            return Gaussians.trusted(*parts, views)
        return Gaussians(*parts, views)  # e.g. a 2-D index: the checked constructor names it

    @property
    def sh_degree(self) -> int:
        return int(math.isqrt(self.sh.shape[1])) - 1

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    def to(self, device=None, dtype: torch.dtype | None = None) -> Gaussians:
        views = None if self.views is None else self.views.to(device=device)
        return Gaussians(
            *(getattr(self, name).to(device=device, dtype=dtype) for name in self.PARAMS), views
        )

    def detach(self) -> Gaussians:
        return Gaussians(*(getattr(self, name).detach() for name in self.PARAMS), self.views)

    def with_sh_degree(self, degree: int) -> Gaussians:
        """Truncate or zero-pad the SH coefficients to ``degree``."""
        k = (degree + 1) ** 2
        sh = (
            self.sh[:, :k]
            if k <= self.sh.shape[1]
            else torch.nn.functional.pad(self.sh, (0, 0, 0, k - self.sh.shape[1]))
        )
        return Gaussians(self.means, self.quats, self.scales, self.opacities, sh, self.views)

    def with_scale_factor(self, factor: float) -> Gaussians:
        """Every Gaussian's standard deviations multiplied by ``factor`` (> 0), nothing else
        changed: 3DGS's render-time "scaling modifier". The generator sizes its Gaussians to
        cover the pixels between them on a black background; where the holes are filled
        anyway (pull-push) smaller ones render sharper (:data:`prosplat.pipeline.enhance.SPLAT_SCALE`)."""
        if isinstance(factor, bool) or not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"scale factor must be a finite number > 0, got {factor!r}")
        if factor == 1:
            return self
        return Gaussians(
            self.means, self.quats, self.scales * factor, self.opacities, self.sh, self.views
        )

    def tensors(self) -> dict[str, Tensor]:
        """The float parameters by name (``views`` is not one of them)."""
        return {name: getattr(self, name) for name in self.PARAMS}
