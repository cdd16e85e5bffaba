"""``python -m prosplat.worker --serve``: one long-lived worker for a whole Blender session.

Starting a Python, importing torch and loading the models takes seconds on every job when
each job gets its own process (measured 25-27 s per Render View on a busy machine, against a
fraction of a second for the render itself). This loop pays that once: it imports torch
before the first request, and :mod:`prosplat.worker.models` keeps the models loaded.

Protocol (one JSON object per line, so any language can drive it):

- stdin: ``{"id": ID, "job": "/path/JOB.json"}`` runs that job file exactly as
  ``python -m prosplat.worker JOB.json`` would (status, cancel and result files beside it);
  ``{"cmd": "ping"}`` asks for the counters; ``{"cmd": "stop"}`` or end of input ends it.
- stdout: ``{"event": "ready", ...}`` once torch is imported, then per request
  ``{"event": "finished", "id": ID, "code": EXIT_*}`` or ``{"event": "pong", ...}``.

Jobs run one after another; a job asked to stop mid-step (``JOB.cancel``) stops at its next
step, and a caller that cannot wait kills the process (the next job starts a new one).
Anything a task prints goes to stderr, never into the protocol stream. The loop also ends
when its parent process goes away (Blender crashed, so no ``stop`` ever comes).
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from typing import IO, Any

from prosplat.worker.jobs import run_job_file
from prosplat.worker.protocol import PROTOCOL, STATS

_PARENT_CHECK_S = 2.0


def _protocol_stream() -> IO[str]:
    """A private copy of stdout for the protocol; fd 1 itself then points at stderr, so a
    stray ``print`` (tqdm, a warning, a library) cannot corrupt a protocol line."""
    out = os.fdopen(os.dup(1), "w", buffering=1)
    sys.stdout.flush()
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return out


def _send(out: IO[str], message: dict[str, Any]) -> None:
    out.write(json.dumps(message, default=str) + "\n")
    out.flush()


def _exit_with_parent(parent: int) -> None:
    """Leave when the process that started us is gone (its pipe may stay open elsewhere)."""
    while True:
        time.sleep(_PARENT_CHECK_S)
        if os.getppid() != parent:
            os._exit(0)


def serve(requests: IO[str] | None = None, out: IO[str] | None = None) -> int:
    """Run jobs named on ``requests`` (default stdin) until ``stop`` or end of input."""
    from prosplat.worker.threads import apply_threads

    # OMP_WAIT_POLICY must be set before torch loads, i.e. by whoever starts this process
    # (the add-on does: addon/core/worker_process.py); importing prosplat already loaded torch.
    requests = requests or sys.stdin
    out = out or _protocol_stream()
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True).start()
    t0 = time.perf_counter()
    import prosplat.worker.tasks  # noqa: F401 - torch now, not during the first job

    threads = apply_threads(None)
    _send(out, {"event": "ready", "protocol": PROTOCOL, "pid": os.getpid(),
                "import_s": round(time.perf_counter() - t0, 3), "threads": threads})  # fmt: skip
    for line in requests:
        line = line.strip()
        if not line:
            continue
        try:
            request = json.loads(line)
            if not isinstance(request, dict):
                raise ValueError("not an object")
        except ValueError as e:
            _send(out, {"event": "error", "error": f"unreadable request {line[:80]!r}: {e}"})
            continue
        cmd = request.get("cmd")
        if cmd == "stop":
            break
        if cmd == "ping":
            from prosplat.worker.models import MODELS

            _send(out, {"event": "pong", "id": request.get("id"), "pid": os.getpid(),
                        "jobs": STATS["jobs"], **MODELS.stats()})  # fmt: skip
            continue
        if not request.get("job"):
            _send(out, {"event": "error", "id": request.get("id"), "error": "no job file given"})
            continue
        try:
            code = run_job_file(request["job"])
        except Exception as e:  # noqa: BLE001 - one bad job must not end the session's worker
            print(f"job {request['job']} failed outside its task: {e!r}", file=sys.stderr)
            code = 1
        _send(out, {"event": "finished", "id": request.get("id"), "job": request["job"],
                    "code": code})  # fmt: skip
    return 0
