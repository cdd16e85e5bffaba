"""Run a :mod:`prosplat.worker` task without freezing Blender: a thread or an external process.

Both kinds of :class:`Job` are polled from Blender's main thread (a modal operator's timer, or
:meth:`Job.wait` in scripts), and neither touches ``bpy``: the task gets plain data in and
gives plain data back, and only the main thread turns that into Blender objects. So a
cancelled or failed job never leaves a half-made object behind.

Both stay warm between jobs: the thread runs in Blender's process, where the loaded models
stay cached (:mod:`prosplat.worker.models`), and external jobs go to the session's one
long-lived worker process (:mod:`.worker_process`) unless *Keep Worker Running* is off.
Every job carries the torch CPU thread count of the preferences (``threads``, 0: automatic).
Which kind a job is, by the preferences, is decided in the Blender layer
(:func:`..blender.runtime.make_job`); this module reads no preferences and imports no ``bpy``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from . import requirements, worker_process

FINISHED = ("done", "error", "cancelled")
_BOOT = worker_process.BOOT
_TERMINATE_AFTER = 5.0  # seconds a cancelled external worker gets to stop by itself


def job_paths(job: Path) -> dict[str, Path]:
    """Status, cancel and result files of a job file: the same names as
    ``prosplat.worker.paths_for`` (which this module cannot import without torch)."""
    stem = job.with_suffix("")
    return {
        "status": stem.with_name(stem.name + ".status.json"),
        "cancel": stem.with_name(stem.name + ".cancel"),
        "arrays": stem.with_name(stem.name + ".result.npz"),
    }


def load_arrays(path: str | Path) -> dict[str, np.ndarray]:
    with np.load(str(path), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


class JobError(RuntimeError):
    """A job failed; the message is meant for the user (``self.report``)."""


class JobCancelled(RuntimeError):
    """A job was cancelled."""


class Job:
    """A task running somewhere; :meth:`poll` updates ``state``, ``progress``, ``message``."""

    def __init__(self, task: str, params: dict[str, Any]) -> None:
        self.task, self.params = task, params
        self.state, self.progress, self.message = "pending", 0.0, "waiting"
        self.result: dict | None = None
        self.error: str | None = None

    @property
    def finished(self) -> bool:
        return self.state in FINISHED

    def start(self) -> Job:
        raise NotImplementedError

    def poll(self) -> bool:
        """Refresh the state; True once finished."""
        raise NotImplementedError

    def cancel(self) -> None:
        raise NotImplementedError

    def wait(self, timeout: float | None = None, interval: float = 0.05) -> dict:
        """Block until finished (scripts, ``execute``); returns the result.

        Raises:
            JobError: the task failed (message for the user). JobCancelled: it was cancelled.
        """
        t0 = time.monotonic()
        while not self.poll():
            if timeout is not None and time.monotonic() - t0 > timeout:
                self.cancel()
                raise JobError(f"{self.task} took longer than {timeout:.0f} s and was stopped")
            time.sleep(interval)
        return self.outcome()

    def outcome(self) -> dict:
        if self.state == "cancelled":
            raise JobCancelled(f"{self.task} was cancelled")
        if self.state == "error":
            raise JobError(self.error or f"{self.task} failed")
        return self.result or {}


class ThreadJob(Job):
    """The task in a thread of Blender's own Python (``prosplat`` must import here)."""

    def start(self) -> ThreadJob:
        requirements.prefer_passive_wait()
        from prosplat.worker import Progress

        self._progress = Progress()
        self._thread = threading.Thread(target=self._run, name=f"prosplat-{self.task}", daemon=True)
        self.state = "running"
        self._thread.start()
        return self

    def _run(self) -> None:
        from prosplat.worker import USER_ERRORS, Cancelled, run_task

        try:
            self.result = run_task(self.task, self.params, self._progress)
            self._final = "done"
        except Cancelled:
            self._final = "cancelled"
        except USER_ERRORS as e:
            self.error, self._final = str(e), "error"
        except Exception as e:  # noqa: BLE001 - reported to the user, never raised into Blender
            self.error, self._final = f"{type(e).__name__}: {e}", "error"

    def poll(self) -> bool:
        if self.state == "running":
            self.progress, self.message = self._progress.fraction, self._progress.message
            if not self._thread.is_alive():
                self.state = self._final
        return self.finished

    def cancel(self) -> None:
        if self.state == "running":
            self._progress.cancel.set()
            self.message = "cancelling (after the current step)"


class ExternalJob(Job):
    """The task in another interpreter: the session's serving worker (``persistent``, the
    default) or, with it off, its own ``python -m prosplat.worker JOB.json`` process.

    Either way the job is a folder of files (job, status, cancel, result), so polling,
    cancelling and errors work the same; a job whose serving worker died before starting it
    is handed once to a new worker.
    """

    def __init__(
        self, task: str, params: dict[str, Any], python: str, persistent: bool = True
    ) -> None:
        super().__init__(task, params)
        self.python, self.persistent = python, persistent
        self._cancel_time: float | None = None
        self.worker: worker_process.WorkerProcess | None = None
        self.proc: subprocess.Popen | None = None
        self._resubmitted = False

    def start(self) -> ExternalJob:
        if not (os.path.isfile(self.python) and os.access(self.python, os.X_OK)):
            raise JobError(
                f"the external Python {self.python!r} is not an executable file; fix it in "
                "the ProSplat preferences or clear it to run in Blender's Python"
            )
        self.dir = Path(tempfile.mkdtemp(prefix="prosplat-job-"))
        params = dict(self.params)
        arrays = params.pop("arrays", None)
        if arrays is not None:
            np.savez(self.dir / "input.npz", **arrays)
            params["arrays_file"] = str(self.dir / "input.npz")
        self.job_file = self.dir / "job.json"
        self.job_file.write_text(json.dumps({"task": self.task, "params": params}))
        self.files = job_paths(self.job_file)
        # The prosplat this add-on found (e.g. the wheel bundled with the extension) goes at the
        # END of the worker's sys.path: the external Python's own packages always win, and the
        # bundled copy only helps a Python that has torch but no prosplat.
        self._root = requirements.prosplat_source_root() or ""
        if self.persistent:
            self._submit()
        else:
            self._log = open(self.dir / "worker.log", "wb")  # noqa: SIM115 - closed in _finish
            self.proc = subprocess.Popen(
                [self.python, "-c", _BOOT, self._root, str(self.job_file)],
                stdout=self._log, stderr=subprocess.STDOUT, cwd=str(self.dir),
                env=worker_process.worker_env(),
            )  # fmt: skip
        self.state = "running"
        return self

    def _submit(self) -> None:
        """Queue the job on the session's worker (a new one if it died); a worker that dies
        on the spot (no prosplat, a broken Python) is left for :meth:`poll` to report."""
        for _ in range(2):
            self.worker = worker_process.get_worker(self.python, self._root)
            try:
                self.worker.submit(self.job_file)
                break
            except OSError:  # died between the check and the write
                continue
        if not self.worker.ready():
            self.message = "starting the worker (importing torch)"

    def _status(self) -> dict | None:
        try:
            return json.loads(self.files["status"].read_text())
        except (OSError, ValueError):
            return None  # not written yet (or mid-rename on an odd filesystem): poll again

    def poll(self) -> bool:
        if self.state != "running":
            return self.finished
        status = self._status()
        if status:
            self.progress = float(status.get("progress", 0.0))
            self.message = str(status.get("message", ""))
        elif self.worker is not None and self.worker.ready():
            self.message = "waiting for the worker (another job is running)"
        if self.persistent:
            return self._poll_served(status)
        code = self.proc.poll()
        if code is None:
            if self._cancel_time and time.monotonic() - self._cancel_time > _TERMINATE_AFTER:
                self.proc.terminate()
                self._cancel_time = time.monotonic() + 1e9  # once
            return False
        self._finish(code, self._status())
        return True

    def _poll_served(self, status: dict | None) -> bool:
        if status and status.get("state") in FINISHED:
            self._finish(0, status)
            return True
        if self.worker.alive():
            if self._cancel_time is None:
                return False
            if status is None:  # still queued behind another job: done here; the worker
                self._finish(None, None)  # finds its folder gone and skips it
                return True
            if time.monotonic() - self._cancel_time > _TERMINATE_AFTER:
                self.worker.kill()  # our step would not stop; the next job starts a new one
            return False
        status = self._status()  # it may have finished just before it went away
        if status and status.get("state") in FINISHED:
            self._finish(0, status)
            return True
        if status is None and not self._resubmitted and self._cancel_time is None:
            self._resubmitted = True  # died before starting this job (e.g. killed for another)
            self._submit()
            return False
        self._finish(self.worker.exit_code(), status)
        return True

    def _finish(self, code: int | None, status: dict | None) -> None:
        if self.proc is not None:
            self._log.close()
        state = (status or {}).get("state")
        if state == "done":
            self.result = status.get("result") or {}
            if self.result.get("arrays_file"):
                self.result["arrays"] = load_arrays(self.result.pop("arrays_file"))
            self.state = "done"
        elif state == "cancelled" or self._cancel_time is not None:
            self.state = "cancelled"
        else:
            self.state = "error"
            self.error = (status or {}).get("error") or self._crash_message(code)
        shutil.rmtree(self.dir, ignore_errors=True)

    def _crash_message(self, code: int | None) -> str:
        if self.worker is not None:
            hint = self.worker.log_tail()
        else:
            try:
                log = (self.dir / "worker.log").read_text(errors="replace")
                hint = " | ".join(log.strip().splitlines()[-6:]) or "no output"
            except OSError:
                hint = "no output"
        return (
            f"the external worker ({self.python}) exited with code {code} before finishing: "
            f"{hint}. Check that this Python has prosplat and its requirements installed."
        )

    def cancel(self) -> None:
        if self.state == "running" and self._cancel_time is None:
            self.files["cancel"].touch()
            self._cancel_time = time.monotonic()
            self.message = "cancelling"


def shutdown_workers() -> None:
    """Stop the session's external worker (``unregister``; ``atexit`` does it at exit too)."""
    worker_process.shutdown()
