"""The worker's protocol: what a job, its status and its result files look like, and the
progress/cancel object every task is handed. No torch here: the add-on imports this in
Blender's own Python."""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from prosplat.core.paths import write_text_atomic

PROTOCOL = 1
# Exit codes of `python -m prosplat.worker`: the status file says the same in words.
EXIT_DONE, EXIT_ERROR, EXIT_CANCELLED, EXIT_USAGE = 0, 1, 3, 2
# Errors whose message is the whole story (bad input); anything else also gets a traceback.
USER_ERRORS = (ValueError, FileNotFoundError, FileExistsError, IsADirectoryError, OSError)


#: Jobs this process has run (reported in every result's ``worker`` entry).
STATS = {"jobs": 0}


class Cancelled(Exception):
    """Raised inside a task when the caller asked it to stop."""


class Progress:
    """What a task calls between steps: reports ``(fraction, message)`` and raises
    :class:`Cancelled` once ``cancel`` is set or ``cancel_check()`` says so."""

    def __init__(
        self,
        callback: Callable[[float, str], None] | None = None,
        cancel_check: Callable[[], bool] | None = None,
    ) -> None:
        self.callback = callback
        self.cancel_check = cancel_check
        self.cancel = threading.Event()
        self.warnings: list[str] = []
        self.fraction, self.message = 0.0, ""

    def cancelled(self) -> bool:
        return self.cancel.is_set() or bool(self.cancel_check and self.cancel_check())

    def __call__(self, fraction: float, message: str) -> None:
        if self.cancelled():
            raise Cancelled(f"cancelled before: {message}")
        self.fraction, self.message = min(max(float(fraction), 0.0), 1.0), message
        if self.callback is not None:
            self.callback(self.fraction, message)

    def warn(self, message: str) -> None:
        """A problem the task worked around (e.g. no enhancement weights): reported, not fatal."""
        self.warnings.append(message)


# ---- files ----------------------------------------------------------------------------------
def paths_for(job: str | Path) -> dict[str, Path]:
    """The files that belong to job file ``job``: status, cancel flag and result arrays."""
    job = Path(job)
    stem = job.with_suffix("")
    return {
        "status": stem.with_name(stem.name + ".status.json"),
        "cancel": stem.with_name(stem.name + ".cancel"),
        "arrays": stem.with_name(stem.name + ".result.npz"),
    }


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON through a temporary sibling and a rename, so a reader never sees half."""
    write_text_atomic(path, json.dumps(data, indent=1, default=str))


def load_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """Arrays saved by the worker (or by the add-on for a job) as a plain dict."""
    with np.load(str(path), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def save_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
