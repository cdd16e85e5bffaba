"""The heavy half of the Blender add-on, runnable in any Python that has ``prosplat``.

Blender's own Python usually has no torch. The add-on therefore describes every job as plain
data (numbers, paths, numpy arrays) and hands it either to :func:`run_task` in a thread of
Blender's Python (when ``prosplat`` imports there) or to an external interpreter::

    python -m prosplat.worker JOB.json

``JOB.json`` is ``{"task": NAME, "params": {...}}``. While it runs the worker rewrites
``JOB.status.json`` atomically (``state`` running/done/error/cancelled, ``progress`` 0-1,
``message``, and at the end ``result`` or ``error``); numpy arrays of a result go to
``JOB.result.npz``. Creating ``JOB.cancel`` asks the worker to stop at its next step; outputs
appear only complete (temporary files renamed into place), so a cancelled or failed job leaves
nothing half-written. The tasks themselves live in :mod:`prosplat.worker.tasks`.

A long-lived worker runs many such jobs and keeps the models loaded between them
(:mod:`prosplat.worker.models`)::

    python -m prosplat.worker --serve

reads one request per line on stdin (``{"id": ..., "job": "/path/JOB.json"}``, or
``{"cmd": "ping"}`` / ``{"cmd": "stop"}``) and answers one JSON line per request on stdout;
the job itself speaks through the same files as above (see :mod:`prosplat.worker.serve`).
A job's params may carry ``"threads"`` (0: automatic), the torch CPU thread count it runs
with (:mod:`prosplat.worker.threads`).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "Cancelled",
    "Progress",
    "load_arrays",
    "main",
    "paths_for",
    "run_task",
    "write_json_atomic",
]

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


def run_task(task: str, params: dict[str, Any], progress: Progress | None = None) -> dict:
    """Run one task in this process; returns its result dict (``warnings`` added).

    Raises:
        ValueError: an unknown task, or bad parameters (the task names the problem).
        Cancelled: ``progress`` was cancelled.
    """
    from prosplat.worker.tasks import TASKS

    if task not in TASKS:
        raise ValueError(f"unknown worker task {task!r}; known: {sorted(TASKS)}")
    if not isinstance(params, dict):
        raise ValueError(f"params of task {task!r} must be an object, got {type(params).__name__}")
    progress = progress or Progress()
    info: dict[str, Any] = {"pid": os.getpid()}
    if "threads" in params:
        from prosplat.worker.threads import apply_threads

        params = dict(params)
        info["threads"] = apply_threads(params.pop("threads"))
    STATS["jobs"] += 1
    result = TASKS[task](params, progress)
    result["warnings"] = list(progress.warnings)
    from prosplat.worker.models import MODELS

    info.update(jobs=STATS["jobs"], **MODELS.stats())
    result["worker"] = info
    return result


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
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1, default=str))
    os.replace(tmp, path)


def load_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """Arrays saved by the worker (or by the add-on for a job) as a plain dict."""
    with np.load(str(path), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def save_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


class _StatusWriter:
    """Throttled status file writer (at most ~10 writes a second while running)."""

    def __init__(self, path: Path, task: str) -> None:
        self.path, self.task, self.last = path, task, 0.0

    def write(self, state: str, progress: float, message: str, **extra: Any) -> None:
        data = {"protocol": PROTOCOL, "task": self.task, "state": state, "pid": os.getpid()}
        data.update(progress=progress, message=message, time=time.time(), **extra)
        write_json_atomic(self.path, data)

    def running(self, fraction: float, message: str) -> None:
        now = time.monotonic()
        if now - self.last >= 0.1:
            self.last = now
            self.write("running", fraction, message)


def run_job_file(job_path: str | Path) -> int:
    """Run the job in ``job_path``, keeping its status file current; returns an exit code."""
    job_path = Path(job_path)
    files = paths_for(job_path)
    try:
        job = json.loads(job_path.read_text())
        task, params = job["task"], job.get("params", {})
    except (OSError, ValueError, KeyError, TypeError) as e:
        _StatusWriter(files["status"], "?").write(
            "error", 0.0, "unreadable job", error=f"cannot read job file {job_path}: {e}"
        )
        return EXIT_ERROR
    status = _StatusWriter(files["status"], task)
    status.write("running", 0.0, "starting")
    progress = Progress(status.running, cancel_check=files["cancel"].exists)
    try:
        if "arrays_file" in params:
            params = {**params, "arrays": load_arrays(params["arrays_file"])}
        result = run_task(task, params, progress)
    except Cancelled:
        status.write("cancelled", progress.fraction, "cancelled")
        return EXIT_CANCELLED
    except USER_ERRORS as e:
        status.write("error", progress.fraction, "failed", error=str(e), kind=type(e).__name__)
        return EXIT_ERROR
    except Exception as e:  # noqa: BLE001 - the status file must say what happened
        msg = f"{type(e).__name__}: {e}"
        status.write("error", progress.fraction, "failed", error=msg, kind=type(e).__name__,
                     traceback=traceback.format_exc())  # fmt: skip
        return EXIT_ERROR
    arrays = result.pop("arrays", None)
    if arrays:
        save_arrays(files["arrays"], arrays)
        result["arrays_file"] = str(files["arrays"])
    status.write("done", 1.0, "done", result=result)
    return EXIT_DONE


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--serve"]:
        from prosplat.worker.serve import serve

        return serve()
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        print(__doc__.strip().split("\n\n")[1], file=sys.stderr)
        print("\nusage: python -m prosplat.worker JOB.json | --serve", file=sys.stderr)
        return EXIT_USAGE
    return run_job_file(argv[0])
