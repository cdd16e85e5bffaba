"""Where ProSplat keeps files it derives: compiled kernels, converted weights, reference venvs."""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "PROSPLAT_CACHE"


def cache_dir() -> Path:
    """``$PROSPLAT_CACHE`` if set (and non-empty), else ``~/.cache/prosplat``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "prosplat"
