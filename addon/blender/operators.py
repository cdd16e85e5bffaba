"""The ProSplat operators: import posed images, import photos (poses found in the worker),
capture inputs, reconstruct, render view, PLY import/export. Each is a thin shell over
:mod:`.steps` run through :mod:`.modal`."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..core import jobs, photos
from . import capture, modal, pointcloud, runtime, steps

RENDER_MODES = [
    ("ACTIVE", "Active Camera", "Render the scene camera"),
    ("SELECTED", "Selected Cameras", "Render every selected camera object"),
    ("FRAMES", "Frame Range", "Render the scene camera at every frame of the scene's range"),
    ("TARGETS", "Target Cameras", "Render the target cameras imported with the inputs"),
]


def settings(context):
    return context.scene.prosplat


class PROSPLAT_OT_import_posed_images(ImportHelper, modal.JobOperator, bpy.types.Operator):
    """Import posed images (transforms.json or a COLMAP text model) as cameras showing them"""

    bl_idname = "prosplat.import_posed_images"
    bl_label = "Import Posed Images"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default="*.json;*.txt", options={"HIDDEN"})
    images_dir: StringProperty(
        name="Images Folder", subtype="DIR_PATH",
        description="Where the images are, if not where the file says (empty: as the file says)",
    )  # fmt: skip
    set_resolution: BoolProperty(
        name="Set Scene Resolution", default=True,
        description="Render at the first image's size so the cameras frame what the images show",
    )  # fmt: skip

    def prepare(self, context):
        return steps.posed_images_job(self.filepath, self.images_dir or None)

    def apply(self, context, result):
        name = steps.inputs_name(self.filepath)
        coll = steps.apply_posed_images(result, context.scene, name, self.set_resolution)
        settings(context).inputs = coll
        targets = steps.targets_of(coll)
        if targets is None:
            return f"imported {len(coll.objects)} posed images into '{coll.name}'"
        settings(context).render_mode = "TARGETS"
        return (f"imported {len(coll.objects)} input images into '{coll.name}' and "
                f"{len(targets.objects)} target cameras into '{targets.name}'")  # fmt: skip


class PROSPLAT_OT_import_photos(ImportHelper, modal.JobOperator, bpy.types.Operator):
    """Find the camera poses of a folder of photos or a video in the worker, then import the
    photos as cameras showing them (pick a photo to take its folder, or a video)"""

    bl_idname = "prosplat.import_photos"
    bl_label = "Import Photos"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default=photos.FILTER_GLOB, options={"HIDDEN"})
    directory: StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})
    pose_dir: StringProperty(
        name="Pose Folder", subtype="DIR_PATH",
        description="Where the poses and the photos' working copies go (empty: beside the "
        "photos, FOLDER_prosplat_poses; an existing one is kept and -2, -3... is used)",
    )  # fmt: skip
    # the defaults of prosplat.poses.PoseOptions (the add-on cannot import it without torch)
    feature_size: IntProperty(
        name="Feature Size", default=1024, min=256, soft_max=3200,
        description="Longest side in pixels the photos are searched for features at: larger "
        "matches more in big photos and takes longer",
    )  # fmt: skip
    max_frames: IntProperty(
        name="Video Frames", default=60, min=2, soft_max=300,
        description="Most frames taken from a video (the sharpest of each equal part)",
    )  # fmt: skip
    set_resolution: BoolProperty(
        name="Set Scene Resolution", default=True,
        description="Render at the first photo's size so the cameras frame what the photos show",
    )  # fmt: skip

    def _path(self) -> str:
        return self.filepath or self.directory

    def invoke(self, context, event):
        self._browsed = True  # execute comes from the file browser: run the job modally
        return ImportHelper.invoke(self, context, event)

    def execute(self, context):
        # minutes of pose estimation must not freeze Blender: after the file browser the job
        # runs modally with progress and Esc (a script's EXEC_DEFAULT call runs to the end)
        if getattr(self, "_browsed", False) and context.window and not bpy.app.background:
            return modal.JobOperator.invoke(self, context, None)
        return modal.JobOperator.execute(self, context)

    def prepare(self, context):
        return steps.photos_job(self._path(), self.pose_dir or None, self.feature_size,
                                self.max_frames)  # fmt: skip

    def apply(self, context, result):
        coll, text = steps.apply_photos(result, context.scene, self.set_resolution)
        settings(context).inputs = coll
        return text


class PROSPLAT_OT_reconstruct(modal.JobOperator, bpy.types.Operator):
    """Turn the input cameras and their images into 3D Gaussians (a point-cloud object)"""

    bl_idname = "prosplat.reconstruct"
    bl_label = "Reconstruct"
    bl_options = {"REGISTER", "UNDO"}

    budget: IntProperty(
        name="Gaussian Budget", default=-1, min=-1,
        description="Most Gaussians to keep (0: automatic pruning only, -1: the preferences')",
    )  # fmt: skip

    refine_seconds: FloatProperty(
        name="Refine Seconds", default=-1.0, min=-1.0, soft_max=60.0,
        description="Seconds to fit the Gaussians to the input images after reconstructing "
        "(0: off, -1: the preferences')",
    )  # fmt: skip

    def prepare(self, context):
        s = settings(context)
        return steps.reconstruct_job(s.inputs, context.scene, context,
                                     None if self.budget < 0 else self.budget,
                                     None if self.refine_seconds < 0 else self.refine_seconds)  # fmt: skip

    def apply(self, context, result):
        s = settings(context)
        name = f"{s.inputs.name if s.inputs else 'ProSplat'} Gaussians"
        obj = steps.apply_gaussians(result, name, context.scene.collection, s.inputs)
        s.gaussians = obj
        return steps.describe_reconstruct(result)


class PROSPLAT_OT_render_view(modal.JobOperator, bpy.types.Operator):
    """Render cameras from the Gaussians and enhance them; files go to the output folder"""

    bl_idname = "prosplat.render_view"
    bl_label = "Render View"
    bl_options = {"REGISTER"}

    def prepare(self, context):
        s = settings(context)
        obj = s.gaussians
        if obj is None and pointcloud.is_gaussians(context.active_object):
            obj = context.active_object
        if obj is None:
            raise ValueError("no Gaussian object chosen; reconstruct or import a PLY first")
        # the views the Gaussians were made from lend the texture (else the panel's inputs)
        own = bpy.data.collections.get(obj.get(pointcloud.INPUTS_PROP, "")) or s.inputs
        targets = steps.target_views(context.scene, s.render_mode, context.selected_objects,
                                     inputs=own)  # fmt: skip
        self._warnings = steps.resolution_warnings(obj, targets, own)
        return steps.render_job(obj, targets, context.scene, s.output_dir, context,
                                own, None, s.save_raw, s.save_depth)  # fmt: skip

    def apply(self, context, result):
        result["warnings"] = [*getattr(self, "_warnings", []), *result.get("warnings", [])]
        steps.apply_render(result)
        return steps.describe_render(result)


class PROSPLAT_OT_import_ply(ImportHelper, modal.JobOperator, bpy.types.Operator):
    """Import a 3DGS PLY (SH degree 0-3) as a Gaussian point cloud"""

    bl_idname = "prosplat.import_ply"
    bl_label = "Import Gaussian PLY"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ply"
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})

    def prepare(self, context):
        return steps.import_ply_job(self.filepath)

    def apply(self, context, result):
        obj = steps.apply_gaussians(result, Path(self.filepath).stem, context.collection)
        settings(context).gaussians = obj
        return f"imported {result['count']:,} Gaussians (SH degree {result['sh_degree']})"


class PROSPLAT_OT_export_ply(ExportHelper, modal.JobOperator, bpy.types.Operator):
    """Export the active Gaussian object as a standard 3DGS PLY"""

    bl_idname = "prosplat.export_ply"
    bl_label = "Export Gaussian PLY"
    bl_options = {"REGISTER"}

    filename_ext = ".ply"
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace an existing file (off: refuse)")  # fmt: skip
    apply_transform: BoolProperty(name="Apply Transform", default=True,
                                  description="Write the Gaussians where the object puts them")  # fmt: skip

    @classmethod
    def poll(cls, context):
        return pointcloud.is_gaussians(context.active_object)

    def prepare(self, context):
        return steps.export_ply_job(context.active_object, self.filepath, self.overwrite,
                                    self.apply_transform)  # fmt: skip

    def apply(self, context, result):
        return f"wrote {result['count']:,} Gaussians to {result['path']}"


class PROSPLAT_OT_capture_inputs(bpy.types.Operator):
    """Render the selected cameras with the scene's engine into posed images (a new folder
    with transforms.json), then use them as the inputs"""

    bl_idname = "prosplat.capture_inputs"
    bl_label = "Capture Inputs"
    bl_options = {"REGISTER", "UNDO"}

    def _start(self, context):
        s = settings(context)
        self._capture = capture.Capture(context.scene, context.selected_objects,
                                        steps.resolve_dir(s.capture_dir, "capture"))  # fmt: skip
        self._capture.begin()

    def _finish(self, context, result_files) -> set[str]:
        folder, result = result_files
        name = f"ProSplat Capture {folder.name}"
        coll = steps.apply_posed_images(result, context.scene, name, set_resolution=False)
        settings(context).inputs = coll
        self.report({"INFO"}, f"captured {len(result['frames'])} views into {folder}")
        return {"FINISHED"}

    def execute(self, context):
        try:
            self._start(context)
            while not self._capture.done:
                self._capture.step()
            runtime.run_sync(*self._capture.transforms_job(), context)
            return self._finish(context, self._capture.finish())
        except (*modal.INPUT_ERRORS, jobs.JobError, RuntimeError) as e:
            if hasattr(self, "_capture"):
                self._capture.abort()
            self.report({"ERROR"}, f"capture inputs failed: {e}")
            return {"CANCELLED"}

    def invoke(self, context, event):
        if context.window is None or bpy.app.background:
            return self.execute(context)
        try:
            self._start(context)
        except modal.INPUT_ERRORS as e:
            self.report({"ERROR"}, f"capture inputs failed: {e}")
            return {"CANCELLED"}
        self._job = None
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _stop(self, context, ret: set[str], level=None, msg: str = "") -> set[str]:
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        context.workspace.status_text_set(None)
        if ret != {"FINISHED"}:
            self._capture.abort()
        if msg:
            self.report(level, msg)
        return ret

    def modal(self, context, event):
        if event.type == "ESC":
            if self._job is not None:
                self._job.cancel()
            return self._stop(
                context, {"CANCELLED"}, {"WARNING"}, "capture cancelled; no files kept"
            )
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        cap = self._capture
        try:
            if not cap.done:
                context.workspace.status_text_set(
                    f"ProSplat capture: rendering {cap.cams[cap.index].name} "
                    f"({cap.index + 1}/{len(cap.cams)}, Esc to cancel)"
                )
                cap.step()
                context.window_manager.progress_update(int(90 * cap.index / len(cap.cams)))
                return {"RUNNING_MODAL"}
            if self._job is None:
                self._job = runtime.make_job(*cap.transforms_job(), context).start()
            if not self._job.poll():
                return {"RUNNING_MODAL"}
            self._job.outcome()
            ret = self._finish(context, cap.finish())
            return self._stop(context, ret)
        except (*modal.INPUT_ERRORS, jobs.JobError, jobs.JobCancelled, RuntimeError) as e:
            return self._stop(context, {"CANCELLED"}, {"ERROR"}, f"capture inputs failed: {e}")


CLASSES = (
    PROSPLAT_OT_import_posed_images,
    PROSPLAT_OT_import_photos,
    PROSPLAT_OT_capture_inputs,
    PROSPLAT_OT_reconstruct,
    PROSPLAT_OT_render_view,
    PROSPLAT_OT_import_ply,
    PROSPLAT_OT_export_ply,
)
