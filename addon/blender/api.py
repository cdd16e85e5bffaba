"""Headless ProSplat for scripts: the panel's steps as functions, no operators or UI needed.

Works in ``python script.py`` (the ``bpy`` module) and ``blender -b -P script.py``; the add-on
does not even have to be enabled (settings default to the preferences' defaults, overridable
per call). Every function runs its worker job to the end and raises ``ValueError`` /
``FileNotFoundError`` (bad input) or :class:`~..core.jobs.JobError` (the job failed) with a message
for the user; nothing half-made is left behind.

    from addon import api            # or: from bl_ext.user_default.prosplat import api
    inputs = api.import_posed_images("scene/transforms.json")
    gaussians = api.reconstruct(inputs)
    views = api.render_views(gaussians, [bpy.context.scene.camera], "out/")
"""

from __future__ import annotations

from pathlib import Path

import bpy

from . import capture, pointcloud, runtime, steps

__all__ = [
    "capture_inputs",
    "export_ply",
    "import_photos",
    "import_ply",
    "import_posed_images",
    "reconstruct",
    "render_views",
]


def _scene(scene):
    return scene or bpy.context.scene


def import_posed_images(path, images_dir=None, name=None, scene=None, set_resolution=True):
    """Cameras (one per image, showing it, named by its file stem) from a transforms.json or
    COLMAP text model, in a new collection linked to the scene; returns the collection.
    Frames marked ``"split": "target"`` go to a second collection of cameras to render
    (``steps.targets_of(collection)``; ``render_views(..., mode="TARGETS")``)."""
    scene = _scene(scene)
    result = runtime.run_sync(*steps.posed_images_job(str(path), images_dir and str(images_dir)))
    name = name or steps.inputs_name(str(path))
    return steps.apply_posed_images(result, scene, name, set_resolution)


def import_photos(path, pose_dir=None, feature_size=None, max_frames=None, scene=None,
                  set_resolution=True):  # fmt: skip
    """Cameras for a folder of photos (or a photo in it) or a video with no poses: the worker
    finds the poses (``prosplat.poses``; pose folder ``pose_dir`` or ``<folder>_prosplat_poses``
    beside the photos), then they are imported as :func:`import_posed_images` imports;
    returns (collection, result dict: ``folder``, ``unregistered``, ``skipped``, ...)."""
    scene = _scene(scene)
    job = steps.photos_job(str(path), pose_dir and str(pose_dir), feature_size, max_frames)
    result = runtime.run_sync(*job)
    coll, _ = steps.apply_photos(result, scene, set_resolution)
    return coll, result


def capture_inputs(cameras, folder, scene=None):
    """Render ``cameras`` (>= 2) with the scene's engine into a new folder under ``folder``
    (images + transforms.json); returns (folder written, input collection)."""
    scene = _scene(scene)
    cap = capture.Capture(scene, cameras, Path(bpy.path.abspath(str(folder))))
    cap.begin()
    try:
        while not cap.done:
            cap.step()
        runtime.run_sync(*cap.transforms_job())
        final, result = cap.finish()
    except BaseException:
        cap.abort()
        raise
    coll = steps.apply_posed_images(result, scene, f"ProSplat Capture {final.name}", False)
    return final, coll


def reconstruct(inputs, name=None, collection=None, budget=None, scene=None, views=None,
                **options):  # fmt: skip
    """Gaussian point-cloud object from the input collection's checked cameras and images.

    ``budget``: most Gaussians kept (None: the preference, 0: automatic). ``views``: how
    to pick when more cameras are checked than the generator takes, ``"spread"`` or
    ``"nearest"`` (the active camera) (None: the scene's setting); the object remembers the
    views used (``steps.VIEWS_PROP``). ``options`` may set
    ``device``, ``weights``, ``max_size``, ``near``, ``far``, ``refine_seconds`` or
    ``refine_steps`` (fit the Gaussians to the inputs; 0: off) (defaults: the
    preferences/data).
    """
    scene = _scene(scene)
    task, params = steps.reconstruct_job(inputs, scene, budget=budget)
    if views is not None:
        params["view_choice"] = steps.view_choice(scene, views)
    params.update({k: v for k, v in options.items() if v is not None})
    if params.get("refine_steps"):
        params["refine_seconds"] = None  # a step count given here replaces the preference's time
    result = runtime.run_sync(task, params)
    target = collection or scene.collection
    return steps.apply_gaussians(result, name or f"{inputs.name} Gaussians", target, inputs)


def render_views(gaussians, cameras=None, output_dir="", mode="ACTIVE", scene=None, inputs=None,
                 enhance=None, save_raw=False, save_depth=False, load_images=True, **options):  # fmt: skip
    """Render camera objects (or ``mode``: ACTIVE / SELECTED / FRAMES of the scene camera /
    TARGETS imported with the inputs) from ``gaussians``, enhanced when weights allow, into
    ``output_dir`` (empty: ``//prosplat_renders``, which needs a saved .blend); returns the
    result dict (``views``: per view the files written, the reference input, timings;
    ``warnings``, e.g. rendering above the input resolution). ``options`` override job
    settings, e.g. ``distill_steps=800``: every view enhanced, the Gaussians fitted to the
    inputs and those views, then all rendered from them (views that agree; no flicker)."""
    scene = _scene(scene)
    if inputs is None:
        inputs = bpy.data.collections.get(gaussians.get(pointcloud.INPUTS_PROP, ""))
    if cameras is not None:
        targets = steps.target_views(scene, "SELECTED", cameras)
    else:
        targets = steps.target_views(scene, mode, bpy.context.selected_objects, inputs=inputs)
    task, params = steps.render_job(gaussians, targets, scene, str(output_dir), None, inputs,
                                    enhance, save_raw, save_depth)  # fmt: skip
    params.update({k: v for k, v in options.items() if v is not None})
    warnings = steps.resolution_warnings(gaussians, targets, inputs)
    result = runtime.run_sync(task, params)
    result["warnings"] = [*warnings, *result.get("warnings", [])]
    if load_images:
        steps.apply_render(result, show=False)
    return result


def import_ply(path, name=None, collection=None):
    """A 3DGS PLY (SH degree 0-3) as a Gaussian point-cloud object."""
    result = runtime.run_sync(*steps.import_ply_job(str(path)))
    target = collection or bpy.context.collection
    return steps.apply_gaussians(result, name or Path(path).stem, target)


def export_ply(obj, path, overwrite=False, apply_transform=True) -> Path:
    """Write a Gaussian object as a standard 3DGS PLY (refuses to replace a file unless
    ``overwrite``); returns the path."""
    result = runtime.run_sync(*steps.export_ply_job(obj, str(path), overwrite, apply_transform))
    return Path(result["path"])
