"""The session's long-lived external worker: one ``python -m prosplat.worker --serve``.

With *External Python* set, each job used to start its own interpreter: importing torch and
loading the models cost 25-27 s per Render View on a busy machine. Now one process serves
the whole Blender session: started lazily by the first job, reused while it lives (models
stay loaded, :mod:`prosplat.worker.models`), started again if it died, and stopped when the
add-on is unregistered or Blender exits (:func:`shutdown`, also registered with ``atexit``).

Requests go in on its stdin, one JSON line per job file; progress, results and cancellation
still travel through the job's files (:mod:`prosplat.worker`), so :class:`~.jobs.ExternalJob`
reads a job the same way whichever process runs it. No ``bpy`` here.
"""

from __future__ import annotations

import atexit
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Any

# `python -c _BOOT ROOT ARGS...`: `python -m prosplat.worker ARGS` with ROOT appended to
# sys.path (the prosplat this add-on found helps only a Python that has none of its own).
BOOT = (
    "import sys; root = sys.argv[1]; root and sys.path.append(root); "
    "from prosplat.worker import main; sys.exit(main(sys.argv[2:]))"
)
_STOP_WAIT = 3.0  # seconds a stopping worker gets before it is killed


def worker_env() -> dict[str, str]:
    """The worker's environment: ours, plus OpenMP told to sleep rather than spin when idle
    (see :mod:`prosplat.worker.threads` for the measurement; a user's setting wins)."""
    env = dict(os.environ)
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    env["PYTHONUNBUFFERED"] = "1"
    return env


class WorkerProcess:
    """One serving worker process; :meth:`submit` queues a job file (jobs run in order)."""

    def __init__(self, python: str, root: str | None) -> None:
        self.python, self.root = python, root or ""
        self.dir = Path(tempfile.mkdtemp(prefix="prosplat-worker-"))
        self.log_path = self.dir / "worker.log"
        self.events: list[dict[str, Any]] = []
        self.submitted = 0
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self.proc: subprocess.Popen | None = None

    def start(self) -> WorkerProcess:
        log = open(self.log_path, "ab")  # noqa: SIM115 - the child holds it; closed below
        try:
            self.proc = subprocess.Popen(
                [self.python, "-c", BOOT, self.root, "--serve"],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, cwd=str(self.dir),
                env=worker_env(), text=True, bufsize=1,
            )  # fmt: skip
        finally:
            log.close()
        self._reader = threading.Thread(target=self._read, name="prosplat-worker-io", daemon=True)
        self._reader.start()
        return self

    def _read(self) -> None:
        for line in self.proc.stdout:
            try:
                self.events.append(json.loads(line))
            except ValueError:
                self.events.append({"event": "noise", "line": line.rstrip()})

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def ready(self) -> bool:
        """True once it has imported torch and waits for jobs."""
        return any(e.get("event") == "ready" for e in self.events)

    def exit_code(self) -> int | None:
        return None if self.proc is None else self.proc.poll()

    def submit(self, job_file: Path) -> int:
        """Queue ``job_file``; returns the request id. Raises OSError if the worker is gone."""
        with self._lock:
            if not self.alive():
                raise BrokenPipeError("the worker process is not running")
            rid = next(self._ids)
            self.proc.stdin.write(json.dumps({"id": rid, "job": str(job_file)}) + "\n")
            self.proc.stdin.flush()
            self.submitted += 1
            return rid

    def log_tail(self, lines: int = 6) -> str:
        try:
            tail = self.log_path.read_text(errors="replace").strip().splitlines()[-lines:]
        except OSError:
            tail = []
        return " | ".join(tail) if tail else "no output"

    def kill(self) -> None:
        """Stop now (a cancelled job that would not stop); the next job starts a new worker."""
        if self.alive():
            self.proc.kill()
            self.proc.wait()

    def stop(self) -> None:
        """Ask it to finish (end of input), kill it if it does not within a few seconds."""
        if self.proc is None:
            return
        try:
            self.proc.stdin.close()
            self.proc.wait(_STOP_WAIT)
        except (OSError, subprocess.TimeoutExpired):
            self.kill()
        shutil.rmtree(self.dir, ignore_errors=True)


_WORKERS: dict[str, WorkerProcess] = {}
#: Worker processes started this session (a restart after a crash counts; tests read it).
STARTS = {"count": 0}
_POOL_LOCK = threading.Lock()


def get_worker(python: str, root: str | None) -> WorkerProcess:
    """The session's worker for ``python``: the running one, or a new one if there is none
    or it died (a worker for another interpreter is stopped: one worker at a time)."""
    with _POOL_LOCK:
        w = _WORKERS.get("current")
        if w is not None and w.alive() and (w.python, w.root) == (python, root or ""):
            return w
        if w is not None:
            w.stop()
        w = _WORKERS["current"] = WorkerProcess(python, root).start()
        STARTS["count"] += 1
        return w


def current_worker() -> WorkerProcess | None:
    return _WORKERS.get("current")


def shutdown() -> None:
    """Stop the session's worker (unregister, Blender exit)."""
    with _POOL_LOCK:
        w = _WORKERS.pop("current", None)
    if w is not None:
        w.stop()


atexit.register(shutdown)
