"""Long work without freezing Blender: a modal operator polls a :class:`~..core.jobs.Job` on a timer.

:class:`JobOperator` is the mixin every long operator uses: ``execute`` runs the job to the
end (scripts, ``blender -b``), ``invoke`` runs it modally with progress in the status bar,
the window-manager progress and the ProSplat panel, and Esc cancels. The event logic lives in
:class:`JobDriver`, a plain class, so tests can drive it without a window.
"""

from __future__ import annotations

import bpy

from ..core import jobs
from . import runtime

#: Errors that are the user's input, reported as they are (no traceback).
INPUT_ERRORS = (ValueError, FileNotFoundError, FileExistsError, IsADirectoryError, OSError)
#: Jobs running now, for the panel: {operator label: driver}.
ACTIVE: dict[str, JobDriver] = {}


def _redraw_panels(context) -> None:
    screen = getattr(context, "screen", None)
    for area in screen.areas if screen else ():
        if area.type == "VIEW_3D":
            area.tag_redraw()


class JobDriver:
    """Drives one job from the main thread: progress UI on every poll, result handling once.

    ``apply(result) -> str`` builds the Blender data and returns the message to report;
    ``report(level_set, text)`` is the operator's ``self.report``.
    """

    def __init__(self, label: str, job: jobs.Job, apply, report) -> None:
        self.label, self.job, self.apply, self.report = label, job, apply, report
        self.cancel_requested = False

    def begin(self, context) -> None:
        ACTIVE[self.label] = self
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._status(context)

    def _status(self, context) -> None:
        pct = int(round(100 * self.job.progress))
        context.window_manager.progress_update(pct)
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            hint = "cancelling..." if self.cancel_requested else "Esc to cancel"
            workspace.status_text_set(f"ProSplat {self.label}: {self.job.message} {pct}% ({hint})")
        _redraw_panels(context)

    def end(self, context) -> None:
        ACTIVE.pop(self.label, None)
        context.window_manager.progress_end()
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(None)
        _redraw_panels(context)

    def event(self, context, event_type: str) -> set[str]:
        """Handle one modal event; returns the operator's return set."""
        if event_type == "ESC" and not self.cancel_requested:
            self.cancel_requested = True
            self.job.cancel()
        elif event_type != "TIMER":
            return {"PASS_THROUGH"}
        if not self.job.poll():
            self._status(context)
            return {"RUNNING_MODAL"}
        self.end(context)
        return self.finish()

    def finish(self) -> set[str]:
        """Report the finished job's outcome and apply its result (all or nothing)."""
        try:
            result = self.job.outcome()
        except jobs.JobCancelled:
            self.report({"WARNING"}, f"{self.label} cancelled; nothing was created")
            return {"CANCELLED"}
        except jobs.JobError as e:
            self.report({"ERROR"}, f"{self.label} failed: {e}")
            return {"CANCELLED"}
        return apply_and_report(self.label, self.apply, result, self.report)


def apply_and_report(label: str, apply, result: dict, report) -> set[str]:
    try:
        message = apply(result)
    except INPUT_ERRORS as e:
        report({"ERROR"}, f"{label} failed: {e}")
        return {"CANCELLED"}
    for w in result.get("warnings", []):
        report({"WARNING"}, w)
    if message:
        report({"INFO"}, message)
    return {"FINISHED"}


class JobOperator:
    """Mixin for operators whose work is one worker job.

    Subclasses define ``prepare(context) -> (task, params)`` (may raise ValueError with a
    message for the user) and ``apply(context, result) -> str``.
    """

    _driver: JobDriver | None = None
    _timer = None

    def _label(self) -> str:
        return self.bl_label.lower()

    def execute(self, context):
        try:
            task, params = self.prepare(context)
            result = runtime.run_sync(task, params, context)
        except INPUT_ERRORS as e:
            self.report({"ERROR"}, f"{self._label()} failed: {e}")
            return {"CANCELLED"}
        except jobs.JobCancelled:
            self.report({"WARNING"}, f"{self._label()} cancelled; nothing was created")
            return {"CANCELLED"}
        except jobs.JobError as e:
            self.report({"ERROR"}, f"{self._label()} failed: {e}")
            return {"CANCELLED"}
        return apply_and_report(
            self._label(), lambda r: self.apply(context, r), result, self.report
        )

    def invoke(self, context, event):
        if context.window is None or bpy.app.background:  # no event loop: run to the end
            return self.execute(context)
        if self._label() in ACTIVE:
            self.report({"ERROR"}, f"{self._label()} is already running; wait or press Esc")
            return {"CANCELLED"}
        try:
            task, params = self.prepare(context)
            job = runtime.make_job(task, params, context).start()
        except (*INPUT_ERRORS, jobs.JobError) as e:
            self.report({"ERROR"}, f"{self._label()} failed: {e}")
            return {"CANCELLED"}
        apply = lambda r: self.apply(bpy.context, r)  # noqa: E731 - the context at the end
        self._driver = JobDriver(self._label(), job, apply, self.report)
        self._driver.begin(context)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        result = self._driver.event(context, event.type)
        if "RUNNING_MODAL" not in result and "PASS_THROUGH" not in result:
            context.window_manager.event_timer_remove(self._timer)
        return result

    def cancel(self, context):
        """Blender ends the operator (file load, quit): stop the job, create nothing."""
        if self._driver is not None:
            self._driver.job.cancel()
            self._driver.end(context)
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
