"""Where ProSplat keeps files: its cache (compiled kernels, converted weights, reference venvs)
and fresh output folders that never clobber earlier results. A leaf module: the CLI, the
benchmarks, the demo and the evaluation ladder all import it, and it imports none of them."""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "PROSPLAT_CACHE"


def cache_dir() -> Path:
    """``$PROSPLAT_CACHE`` if set (and non-empty), else ``~/.cache/prosplat``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "prosplat"


def fresh_folder(path: Path, overwrite: bool) -> Path:
    """``path`` if it is new, empty, or ``overwrite``; otherwise the first free ``path-N``.

    Earlier results are never clobbered by a re-run unless the user asks.
    """
    if overwrite or not path.exists() or not any(path.iterdir()):
        return path
    k = 2
    while (candidate := path.with_name(f"{path.name}-{k}")).exists() and any(candidate.iterdir()):
        k += 1
    return candidate
