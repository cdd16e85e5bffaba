"""Add-on preferences: where the heavy work runs and with what, and the requirement check /
install buttons that get a GUI user unstuck when Blender's Python has no torch."""

from __future__ import annotations

import platform

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ..core import depthsplat_file, install, requirements, worker_process
from . import native_splats, runtime

DEVICES = [
    ("AUTO", "Auto", "CUDA if available, then Apple MPS, then the CPU"),
    ("CPU", "CPU", "Run on the CPU"),
    ("CUDA", "CUDA", "Run on an NVIDIA GPU"),
    ("MPS", "MPS", "Run on Apple silicon"),
]
TORCH_BUILDS = [
    ("CPU", "CPU", "torch's CPU build from the PyTorch CPU index (about 230 MB; any machine)"),
    ("CUDA", "CUDA", "torch's CUDA build and NVIDIA libraries (about 3 GB; NVIDIA GPUs)"),
]
FILL_HOLES = [  # the worker's fill_holes modes (prosplat.worker.tasks.FILL_MODES)
    ("RAW", "Raw Renders",
     "Fill the holes of raw renders only (enhancement off or refused, distilled views); "
     "enhanced views stay as the model made them"),
    ("ALL", "All Renders",
     "Also blend enhanced views with the fill where the Gaussians leave holes (level in "
     "PSNR, slightly worse in LPIPS on the test scenes)"),
    ("OFF", "Off", "Show black where no input saw the scene"),
]  # fmt: skip
_STATUS: dict[str, object] = {}


class PROSPLAT_OT_check_requirements(bpy.types.Operator):
    """Check whether prosplat and its requirements import in Blender's Python"""

    bl_idname = "prosplat.check_requirements"
    bl_label = "Check Requirements"

    def execute(self, context):
        runtime.add_deps_to_path()
        requirements.reset_import_check()
        _STATUS["versions"] = requirements.requirement_versions()
        err = requirements.check_prosplat_import()
        _STATUS["import_error"] = err
        if err is None:
            self.report({"INFO"}, "prosplat imports in Blender's Python: ready")
        else:
            self.report({"WARNING"}, f"prosplat does not import here: {err}")
        return {"FINISHED"}


class PROSPLAT_OT_install_requirements(bpy.types.Operator):
    """Install torch and prosplat's other requirements (the tested versions) into a folder of
    the add-on with Blender's pip; shows the download size and asks first"""

    bl_idname = "prosplat.install_requirements"
    bl_label = "Install Requirements"

    confirmed: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    def _build(self, context) -> str:
        return str(getattr(runtime.prefs(context), "torch_build", "CPU"))

    def _start(self, context):
        p = runtime.prefs(context)
        return install.start_install(
            runtime.deps_dir(), getattr(p, "pip_args", ""), self._build(context)
        )

    def draw(self, context):
        col = self.layout.column()
        col.label(text=install.describe_download(self._build(context)), icon="INFO")
        col.label(text=f"into {runtime.deps_dir()}")
        col.label(text=f"tested on {install.pins.TESTED_ON}; Blender's numpy is kept")
        col.label(text=f"this Blender: {detected()}")
        problem = install.numpy_problem()
        if problem:
            col.label(text=problem, icon="ERROR")

    def execute(self, context):
        if not self.confirmed and context.window is not None and not bpy.app.background:
            # OK in the confirmation dialog: run modally, with progress, rather than block
            bpy.ops.prosplat.install_requirements("INVOKE_DEFAULT", confirmed=True)
            return {"FINISHED"}
        run = self._start(context)  # background/scripts: wait for pip
        run.wait()
        return self._report(context, run)

    def invoke(self, context, event):
        if "run" in install.CURRENT and not install.CURRENT["run"].poll():
            self.report({"ERROR"}, "an install is already running")
            return {"CANCELLED"}
        if not self.confirmed:
            return context.window_manager.invoke_props_dialog(
                self, width=480, title="Install Requirements?", confirm_text="Download and Install"
            )
        self._run = self._start(context)
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._run.cancel()
        if event.type not in ("TIMER", "ESC"):
            return {"PASS_THROUGH"}
        context.window_manager.progress_update(int(100 * self._run.fraction))
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        if not self._run.poll():
            return {"RUNNING_MODAL"}
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        return self._report(context, self._run)

    def _report(self, context, run) -> set[str]:
        ok, line = run.summary()
        _STATUS["install"] = (ok, line)
        if not ok:
            self.report({"ERROR"}, line)
            return {"CANCELLED"}
        bpy.ops.prosplat.check_requirements()
        self.report({"INFO"}, f"{line}; installed into {runtime.deps_dir()}")
        return {"FINISHED"}


class PROSPLAT_OT_stop_worker(bpy.types.Operator):
    """Stop the external worker process (it frees its memory; the next job starts a new one)"""

    bl_idname = "prosplat.stop_worker"
    bl_label = "Stop Worker"

    def execute(self, context):
        worker_process.shutdown()
        self.report({"INFO"}, "the ProSplat worker was stopped; the next job starts a new one")
        return {"FINISHED"}


class ProSplatPreferences(bpy.types.AddonPreferences):
    bl_idname = runtime.PACKAGE

    device: EnumProperty(name="Device", items=DEVICES, default="AUTO")
    weights_path: StringProperty(
        name="Generator Weights", subtype="FILE_PATH",
        description="A generator checkpoint: prosplat's (.safetensors) or a DepthSplat "
        "depthsplat-gs-*.pth you downloaded (README, 'DepthSplat weights'); empty: the weights "
        "shipped with prosplat",
    )  # fmt: skip
    improve_weights_path: StringProperty(
        name="Enhancement Weights", subtype="FILE_PATH",
        description="An improvement-model checkpoint; empty: the shipped one, if any",
    )  # fmt: skip
    enhance: BoolProperty(
        name="Enhance Renders", default=True,
        description="Run the improvement model (stage 2) on each render; off: raw renders",
    )  # fmt: skip
    fill_holes: EnumProperty(
        name="Fill Holes", items=FILL_HOLES, default=runtime.Defaults.fill_holes,
        description="Where no input saw the scene, show a continuation of the render's own "
        "colours instead of black. The shipped generator leaves those places empty: a raw "
        "render on black loses about 9 dB",
    )  # fmt: skip
    budget: IntProperty(
        name="Gaussian Budget", default=0, min=0,
        description="Most Gaussians a reconstruction keeps (0: automatic, lossless pruning only)",
    )  # fmt: skip
    merge_flat: BoolProperty(
        name="Merge Flat Blocks", default=runtime.Defaults.merge_flat,
        description="Merge flat 2x2 blocks of Gaussians made above the generator's matching "
        "size into one each: about a third fewer points at Input Size 512, at level quality, "
        "for a lighter viewport and a smaller PLY; renders are not faster",
    )  # fmt: skip
    refine_seconds: FloatProperty(
        name="Refine Seconds", default=runtime.Defaults.refine_seconds, min=0.0, soft_max=60.0,
        description="After reconstructing, fit the Gaussians to the input images for this many "
        "seconds (0: off). The default 3 s is about 100-200 steps at Input Size 128 (fewer at "
        "512), which measured +0.2 dB on enhanced new views at 128 px (100 steps, generator "
        "v16, stage 2 v22); Esc cancels",
    )  # fmt: skip
    distill_steps: IntProperty(
        name="Distill Steps", default=runtime.Defaults.distill_steps, min=0, soft_max=2000,
        description="Render View: first enhance every view to render, fit the Gaussians to the "
        "inputs and those views for this many steps, then render all of them from the fitted "
        "Gaussians: views that agree with each other, an animation without flicker (0: off, "
        "each view enhanced on its own; after Refine Seconds, 800 steps measured +0.13 dB over "
        "the views enhanced one by one at 64 px, level at 128 px, about 30 s per 8 views at "
        "64 px). Esc cancels",
    )  # fmt: skip
    max_input_size: IntProperty(
        name="Input Size", default=runtime.Defaults.max_input_size, min=32, soft_max=1024,
        description="Long side (pixels) input images are scaled to: the size the Gaussians "
        "are made at (one per input pixel, up to 4x the generator's size), refinement fits and "
        "stage 2's references come at. The generator matches the views at the size its "
        "weights were trained at (128 px high for the shipped ones) when that is smaller. "
        "The default 512 suits cameras that render 512 px to 1080p; lower is faster",
    )  # fmt: skip
    python_path: StringProperty(
        name="External Python", subtype="FILE_PATH",
        description="A Python with prosplat installed that runs the heavy work through files "
        "(empty: Blender's own Python)",
    )  # fmt: skip
    pip_args: StringProperty(
        name="Extra pip Arguments",
        description="Added to both pip runs, e.g. --proxy URL, or --find-links DIR for offline wheels",
    )  # fmt: skip
    torch_build: EnumProperty(name="torch Build", items=TORCH_BUILDS, default="CPU")
    threads: IntProperty(
        name="CPU Threads", default=0, min=0, soft_max=32,
        description="torch threads per job (0: automatic, the physical cores up to 4, fewer "
        "where idle threads would spin). Applies from the next job",
    )  # fmt: skip
    keep_worker: BoolProperty(
        name="Keep Worker Running", default=True,
        description="Run every external job in one process that keeps the models loaded "
        "(off: a new process per job, seconds slower each time)",
    )  # fmt: skip

    def draw(self, context):
        layout = self.layout
        col = layout.column()
        col.prop(self, "device")
        col.prop(self, "weights_path")
        draw_depthsplat_note(col, self)
        col.prop(self, "improve_weights_path")
        col.prop(self, "enhance")
        col.prop(self, "fill_holes")
        col.prop(self, "budget")
        col.prop(self, "merge_flat")
        col.prop(self, "refine_seconds")
        col.prop(self, "distill_steps")
        col.prop(self, "max_input_size")
        col.prop(self, "threads")
        box = layout.box()
        box.label(text="Where the heavy work runs", icon="SCRIPTPLUGINS")
        box.prop(self, "python_path")
        if self.python_path.strip():
            box.label(text="Jobs run in the external Python above (it needs prosplat installed).")
            row = box.row()
            row.prop(self, "keep_worker")
            w = worker_process.current_worker()
            if w is not None and w.alive():
                row.label(text=f"worker running (pid {w.pid}, {w.submitted} jobs)")
                row.operator(PROSPLAT_OT_stop_worker.bl_idname, icon="CANCEL")
        draw_requirements(box, self)


def draw_depthsplat_note(layout, prefs) -> None:
    """Under a DepthSplat ``.pth`` in *Generator Weights*: its licence and the *Input Size*
    that matches its training resolution, read from the file name (no file read while
    drawing; the worker reads the real variant and the reconstruct report names it)."""
    path = str(getattr(prefs, "weights_path", "") or "")
    if not depthsplat_file.is_depthsplat_path(path):
        return
    h = depthsplat_file.hint(path)
    box = layout.box()
    for i, line in enumerate(
        h.lines(int(getattr(prefs, "max_input_size", runtime.Defaults.max_input_size)))
    ):
        icon = "INFO" if i == 0 else "NONE"
        if h.depth_only or (line == h.licence and "non-commercial" in line):
            icon = "ERROR"
        box.label(text=line, icon=icon)


def detected() -> str:
    """The Blender and Python this add-on runs in, and how it shows Gaussians there (a
    feature check: Blender's own splats from 5.3, else the mesh display)."""
    try:
        import numpy

        numpy_version = numpy.__version__
    except ImportError:  # pragma: no cover - every Blender bundles numpy
        numpy_version = "missing"
    shown = ("Blender's own Gaussian splats" if native_splats.supported()
             else "mesh + Geometry Nodes splats")  # fmt: skip
    return (f"Blender {bpy.app.version_string}, Python {platform.python_version()}, "
            f"numpy {numpy_version}; Gaussians shown as {shown}")  # fmt: skip


def draw_requirements(layout, prefs) -> None:
    layout.label(text=f"Detected: {detected()}", icon="BLENDER")
    versions = _STATUS.get("versions") or requirements.requirement_versions()
    grid = layout.grid_flow(columns=2, even_columns=True)
    for name, version in versions.items():
        grid.label(text=f"{name}: {version or 'missing'}", icon="CHECKMARK" if version else "ERROR")
    err = _STATUS.get("import_error", "unchecked")
    if err is None:
        layout.label(text="prosplat imports in Blender's Python", icon="CHECKMARK")
    elif err != "unchecked":
        layout.label(text=f"prosplat does not import: {str(err)[:120]}", icon="ERROR")
    row = layout.row()
    row.operator(PROSPLAT_OT_check_requirements.bl_idname, icon="FILE_REFRESH")
    run = install.CURRENT.get("run")
    if run is not None and not run.poll():
        row.enabled = False
        layout.progress(factor=run.fraction, type="BAR", text=run.last_line[:80])
    else:
        row.operator(PROSPLAT_OT_install_requirements.bl_idname, icon="IMPORT")
    layout.prop(prefs, "torch_build")
    layout.label(text=install.describe_download(prefs.torch_build), icon="INFO")
    layout.prop(prefs, "pip_args")
    if "install" in _STATUS:
        ok, line = _STATUS["install"]
        layout.label(text=line[:160], icon="CHECKMARK" if ok else "ERROR")


CLASSES = (
    PROSPLAT_OT_check_requirements,
    PROSPLAT_OT_install_requirements,
    PROSPLAT_OT_stop_worker,
    ProSplatPreferences,
)
