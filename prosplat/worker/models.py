"""Loaded models kept between worker jobs, so only the first job of a session pays for them.

A warm worker (the add-on's thread in Blender, or one long-lived ``python -m prosplat.worker
--serve``) runs many jobs. Loading the generator and the improvement model costs seconds,
rasterizing and enhancing one 128-px view a fraction of one, so the models stay loaded:
the generator keyed by (weights file, device), the improvement model by (its file, device)
(a file is its path, size and modification time, so retraining into it reloads it),
held apart so that Reconstruct (generator only) and Render View (both) do not evict each
other. One of each is kept: a different path or device replaces it (models can be large).

``loads`` counts real loads; tests assert on it (a second job must not reload), and every
job's result reports it under ``worker``.
"""

from __future__ import annotations

import copy
import threading
from pathlib import Path
from typing import Any

import torch

_NO_IMPROVER = "none"


def _file_key(path: str) -> tuple:
    """A path with its size and modification time: a checkpoint retrained into the same
    file is a different model, and must not be served from the cache."""
    try:
        st = Path(path).stat()
    except OSError:
        return (path, None, None)
    return (path, st.st_size, st.st_mtime_ns)


def load_generator(weights: str | None, device: torch.device):
    """A :class:`~prosplat.pipeline.model.ProSplat` without stage 2 for one generator file: None
    -> the shipped weights, a ``.safetensors`` -> a prosplat generator, a ``.pth`` (``.pt``,
    ``.ckpt``) -> a DepthSplat checkpoint through ``from_pretrained(generator=...)``, at the
    size each job asks for. A DepthSplat file that does not load is a ValueError naming the
    file and what is wrong with it, on one line (the add-on shows it in the status bar)."""
    from prosplat.pipeline.model import ProSplat, is_depthsplat_file

    if not is_depthsplat_file(weights):
        return ProSplat.from_pretrained(weights or None, device=device, improve=False)
    try:
        return ProSplat.from_pretrained(generator=weights, device=device, improve=False)
    except ValueError as e:
        text = " ".join(str(e).split())
        raise ValueError(f"the DepthSplat generator file could not be used: {text}") from e


class ModelCache:
    """The worker's loaded generator and improvement model (thread-safe: two in-process jobs
    may ask at once; the second waits for the first one's load instead of loading twice)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._generator: tuple[tuple, Any] | None = None
        self._improver: tuple[tuple, Any] | None = None
        self.loads = {"generator": 0, "improver": 0}
        self.hits = 0

    def clear(self) -> None:
        with self._lock:
            self._generator = self._improver = None

    @staticmethod
    def _improver_path(improve: str | bool | None) -> str:
        """The file ``improve`` names: False -> none; None -> the shipped one, if present."""
        if improve is False:
            return _NO_IMPROVER
        if improve is None or improve is True:
            from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS

            if not Path(DEFAULT_IMPROVE_WEIGHTS).is_file():
                if improve is True:
                    raise FileNotFoundError(
                        f"no shipped improvement-model weights ({DEFAULT_IMPROVE_WEIGHTS})"
                    )
                return _NO_IMPROVER
            return str(DEFAULT_IMPROVE_WEIGHTS)
        return str(improve)

    def get(self, weights: str | None, device: torch.device, improve: str | bool | None = False):
        """A :class:`~prosplat.pipeline.model.ProSplat` with the generator ``weights`` (None: the
        shipped one) and the improvement model ``improve`` (path; None: the shipped one if
        any; False: none), loading only what is not loaded yet.

        The returned object is a shallow copy that shares the cached modules: setting its
        ``improver`` never changes what the next job gets.
        """
        from prosplat.improve.io import load_improver

        gen_key = (_file_key(str(weights)) if weights else "", str(device))
        imp_path = self._improver_path(improve)
        imp_key = (_file_key(imp_path), str(device))
        with self._lock:
            hit = True
            if self._generator is None or self._generator[0] != gen_key:
                self._generator = None  # free the old one before loading the new one
                base = load_generator(weights, device)
                self._generator = (gen_key, base)
                self.loads["generator"] += 1
                hit = False
            if imp_path != _NO_IMPROVER and (
                self._improver is None or self._improver[0] != imp_key
            ):
                self._improver = None
                self._improver = (imp_key, load_improver(imp_path, device=device))
                self.loads["improver"] += 1
                hit = False
            self.hits += hit
            model = copy.copy(self._generator[1])
            model.improver = None if imp_path == _NO_IMPROVER else self._improver[1]
        return model

    def stats(self) -> dict[str, Any]:
        return {"model_loads": dict(self.loads), "model_cache_hits": self.hits}


#: The cache every task of this process uses.
MODELS = ModelCache()
