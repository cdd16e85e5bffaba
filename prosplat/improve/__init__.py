"""Stage 2: the one-step diffusion improvement model with MORI and DWEA.

The geometry (:mod:`.epipolar`, :mod:`.mori`) imports only torch; the network (:mod:`.model`,
built from diffusers) is imported on first use, so ``import prosplat`` stays fast.
"""

from prosplat.improve.config import TINY, ImproveConfig
from prosplat.improve.epipolar import epipolar_distances, fundamental_matrices, fundamental_matrix
from prosplat.improve.mori import mori_scores, overlap_scores, select_reference

_LAZY = {
    "ImproveModel": "prosplat.improve.model",
    "save_improver": "prosplat.improve.io",
    "load_improver": "prosplat.improve.io",
    "DEFAULT_IMPROVE_WEIGHTS": "prosplat.improve.io",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'prosplat.improve' has no attribute {name!r}")


__all__ = [
    "DEFAULT_IMPROVE_WEIGHTS",
    "TINY",
    "ImproveConfig",
    "ImproveModel",
    "epipolar_distances",
    "fundamental_matrices",
    "fundamental_matrix",
    "load_improver",
    "mori_scores",
    "overlap_scores",
    "save_improver",
    "select_reference",
]
