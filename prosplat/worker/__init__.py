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

from prosplat.worker.cli import main
from prosplat.worker.jobs import run_job_file, run_task
from prosplat.worker.protocol import (
    EXIT_CANCELLED,
    EXIT_DONE,
    EXIT_ERROR,
    EXIT_USAGE,
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

__all__ = [
    "EXIT_CANCELLED",
    "EXIT_DONE",
    "EXIT_ERROR",
    "EXIT_USAGE",
    "PROTOCOL",
    "STATS",
    "USER_ERRORS",
    "Cancelled",
    "Progress",
    "load_arrays",
    "main",
    "paths_for",
    "run_job_file",
    "run_task",
    "save_arrays",
    "write_json_atomic",
]
