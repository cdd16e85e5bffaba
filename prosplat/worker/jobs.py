"""Running a job: one task in this process (:func:`run_task`), or a job file with its status
file kept current (:func:`run_job_file`).
The tasks (and torch) are imported only when a job runs."""

from __future__ import annotations

import json
import os
import time
import traceback
from pathlib import Path
from typing import Any

from prosplat.worker.protocol import (
    EXIT_CANCELLED,
    EXIT_DONE,
    EXIT_ERROR,
    PROTOCOL,
    STATS,
    USER_ERRORS,
    Cancelled,
    Progress,
    load_arrays,
    paths_for,
    save_arrays,
    write_json_atomic,
)


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
