"""Blender camera objects <-> the plain camera dicts of :mod:`prosplat.convert.posed`.

Only values are read or written here; the projection maths lives in
:mod:`prosplat.convert.blender` and runs in the worker. A Blender scene has one resolution,
but posed images may differ in size, so each imported or captured camera remembers the size
(and pixel aspect) of its own image in custom properties; the image file is remembered too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import bpy
from mathutils import Matrix

IMAGE_PROP = "prosplat_image"
SIZE_PROP = "prosplat_size"  # [w, h] of the camera's image
USE_PROP = "prosplat_use"  # a registered Object bool: the input's *Use* box in the panel
ASPECT_PROP = "prosplat_pixel_aspect"  # [x, y]


def render_size(scene) -> tuple[int, int]:
    """The pixel size Blender renders (resolution x percentage, truncated, as Blender does)."""
    r = scene.render
    pct = r.resolution_percentage
    return r.resolution_x * pct // 100, r.resolution_y * pct // 100


def _check_perspective(obj) -> None:
    if obj is None or obj.type != "CAMERA":
        raise ValueError(f"{getattr(obj, 'name', obj)!r} is not a camera object")
    if obj.data.type != "PERSP":
        raise ValueError(
            f"camera '{obj.name}' is {obj.data.type.lower()}; ProSplat needs perspective cameras"
        )


def camera_dict(obj, scene, size: tuple[int, int] | None = None) -> dict[str, Any]:
    """The blender camera dict of ``obj`` as it renders in ``scene`` (at ``size`` if given)."""
    _check_perspective(obj)
    d = obj.data
    w, h = size or render_size(scene)
    return {
        "matrix_world": [list(row) for row in obj.matrix_world],
        "lens": d.lens,
        "sensor_width": d.sensor_width,
        "sensor_height": d.sensor_height,
        "sensor_fit": d.sensor_fit,
        "shift_x": d.shift_x,
        "shift_y": d.shift_y,
        "width": int(w),
        "height": int(h),
        "pixel_aspect_x": scene.render.pixel_aspect_x,
        "pixel_aspect_y": scene.render.pixel_aspect_y,
    }


def image_path(obj) -> str | None:
    """The image an input camera was taken with: its remembered file, else the file of its
    first background image; None when it has neither (or the file is gone)."""
    path = obj.get(IMAGE_PROP)
    if not path:
        for bg in getattr(obj.data, "background_images", []):
            if bg.image is not None and bg.image.filepath:
                path = bpy.path.abspath(bg.image.filepath, library=bg.image.library)
                break
    return str(path) if path and Path(path).is_file() else None


def input_frame(obj, scene) -> dict[str, Any]:
    """``{"name", "image", "camera"}`` for an input camera; the size is the one remembered
    for its image (the worker checks it against the file)."""
    size = obj.get(SIZE_PROP)
    cam = camera_dict(obj, scene, (int(size[0]), int(size[1])) if size else None)
    aspect = obj.get(ASPECT_PROP)
    if aspect:
        cam["pixel_aspect_x"], cam["pixel_aspect_y"] = float(aspect[0]), float(aspect[1])
    return {"name": obj.name, "image": image_path(obj), "camera": cam}


def input_cameras(collection) -> list:
    """The camera objects of an input collection (and its children), sorted by name."""
    if collection is None:
        raise ValueError("no input collection chosen; import or capture posed images first")
    cams = [o for o in collection.all_objects if o.type == "CAMERA"]
    if not cams:
        raise ValueError(f"collection '{collection.name}' has no cameras")
    return sorted(cams, key=lambda o: o.name)


def is_used(obj) -> bool:
    """Whether an input camera's *Use* box is checked (True where the add-on's property is
    not registered, e.g. a script that never enabled it)."""
    return bool(getattr(obj, USE_PROP, True))


def input_frames(collection, scene, used_only=False, names=None) -> list[dict[str, Any]]:
    """Frames of the cameras in ``collection`` (``used_only``: those whose *Use* box is
    checked; ``names``: those named, where they still exist, in the order of ``names``, which
    is the order a reconstruction numbered its views in); raises naming each camera without
    an image."""
    objs = input_cameras(collection)
    if used_only:
        objs = [o for o in objs if is_used(o)]
    if names:
        order = {str(n): i for i, n in enumerate(names)}
        wanted = sorted((o for o in objs if o.name in order), key=lambda o: order[o.name])
        objs = wanted or objs  # renamed or deleted since: every camera lends texture
    frames = [input_frame(o, scene) for o in objs]
    missing = [f["name"] for f in frames if not f["image"]]
    if missing:
        raise ValueError(
            f"camera(s) {', '.join(missing[:5])} in '{collection.name}' have no image file; give "
            "each input camera a background image (or re-import the posed images)"
        )
    return frames


def apply_camera(obj, cam: dict[str, Any]) -> None:
    """Set ``obj`` (a camera object) to the values of a blender camera dict."""
    d = obj.data
    d.type = "PERSP"
    d.lens_unit = "MILLIMETERS"
    d.sensor_fit = cam["sensor_fit"]
    d.sensor_width = cam["sensor_width"]
    d.sensor_height = cam["sensor_height"]
    d.lens = cam["lens"]
    d.shift_x = cam["shift_x"]
    d.shift_y = cam["shift_y"]
    obj.matrix_world = Matrix(cam["matrix_world"])
    obj[SIZE_PROP] = [int(cam["width"]), int(cam["height"])]
    obj[ASPECT_PROP] = [
        float(cam.get("pixel_aspect_x", 1.0)),
        float(cam.get("pixel_aspect_y", 1.0)),
    ]


def new_camera(name: str, cam: dict[str, Any], image: str | None, collection, far=None):
    """A camera object placed from ``cam`` in ``collection``, showing ``image`` behind it."""
    data = bpy.data.cameras.new(name)
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    apply_camera(obj, cam)
    if far:
        data.clip_end = max(data.clip_end, 1.5 * float(far))
    if image:
        obj[IMAGE_PROP] = str(image)
        img = bpy.data.images.load(str(image), check_existing=True)
        bg = data.background_images.new()
        bg.image = img
        bg.alpha = 1.0
        data.show_background_images = True
    return obj


def set_scene_resolution(scene, cam: dict[str, Any]) -> None:
    """Make ``scene`` render at the camera's image size and pixel aspect (percentage 100)."""
    r = scene.render
    r.resolution_x, r.resolution_y = int(cam["width"]), int(cam["height"])
    r.resolution_percentage = 100
    r.pixel_aspect_x = float(cam.get("pixel_aspect_x", 1.0))
    r.pixel_aspect_y = float(cam.get("pixel_aspect_y", 1.0))
