"""Capture inputs: render chosen scene cameras with the scene's own engine into posed images.

One camera renders per :meth:`Capture.step`, so a modal operator can show progress and stop
between renders. Files go to a hidden ``.NAME.partial-PID`` folder that is renamed into
place only once ``transforms.json`` is written: a cancelled or failed capture leaves nothing
behind, and an existing folder is never written into (a numbered sibling is used instead).
Near/far per view come from the bounding boxes of the visible meshes (scene data, not guesses).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import bpy
import numpy as np

from . import cameras, pointcloud


def free_folder(folder: Path) -> Path:
    """``folder`` if it is missing or empty, else the first free ``folder-2``, ``folder-3``..."""
    candidate, k = folder, 1
    while candidate.exists() and (not candidate.is_dir() or any(candidate.iterdir())):
        k += 1
        candidate = folder.with_name(f"{folder.name}-{k}")
    return candidate


def _boxes(scene) -> list[np.ndarray]:
    """World-space corners [8, 3] of every visible mesh that is not a Gaussian point cloud."""
    boxes = []
    for obj in scene.objects:
        if obj.type != "MESH" or obj.hide_render or pointcloud.is_gaussians(obj):
            continue
        corners = np.array([list(c) + [1.0] for c in obj.bound_box])  # [8, 4] local
        boxes.append(corners @ np.array(obj.matrix_world).T[:, :3])
    return boxes


def depth_range(scene, cam_obj) -> tuple[float, float] | None:
    """(near, far) z-depth bounds of the scene's meshes in ``cam_obj``, or None if none."""
    boxes = _boxes(scene)
    if not boxes:
        return None
    m = np.array(cam_obj.matrix_world.normalized())
    centre, forward = m[:3, 3], -m[:3, 2]  # Blender cameras look down their local -Z
    pts = np.concatenate(boxes)
    far = float(((pts - centre) @ forward).max())
    gaps = [np.maximum(np.maximum(b.min(0) - centre, centre - b.max(0)), 0.0) for b in boxes]
    near = max(cam_obj.data.clip_start, min(float(np.linalg.norm(g)) for g in gaps))
    if far <= near:
        return None
    return near, far * 1.05


class _ImageSettings:
    """Temporarily write 8-bit RGB PNG (restoring the user's output settings after)."""

    KEYS = ("media_type", "file_format", "color_mode", "color_depth")

    def __init__(self, scene) -> None:
        self.settings = scene.render.image_settings
        self.saved = {k: getattr(self.settings, k) for k in self.KEYS if hasattr(self.settings, k)}

    def __enter__(self):
        s = self.settings
        if hasattr(s, "media_type"):
            s.media_type = "IMAGE"
        s.file_format, s.color_mode, s.color_depth = "PNG", "RGB", "8"
        return self

    def __exit__(self, *exc) -> None:
        for k, v in self.saved.items():
            try:
                setattr(self.settings, k, v)
            except (TypeError, ValueError):  # e.g. a depth the restored format lacks
                pass


class Capture:
    """Render ``cams`` of ``scene`` one per :meth:`step` into a new folder under ``folder``."""

    def __init__(self, scene, cams, folder: str | Path) -> None:
        cams = sorted(
            {c.name: c for c in cams if c.type == "CAMERA"}.values(), key=lambda c: c.name
        )
        if len(cams) < 2:
            raise ValueError("select at least 2 camera objects to capture (inputs are posed views)")
        for c in cams:
            cameras.camera_dict(c, scene)  # raises for non-perspective cameras
        self.scene, self.cams = scene, cams
        self.final = free_folder(Path(folder))
        self.tmp = self.final.with_name(f".{self.final.name}.partial-{os.getpid()}")
        self.frames: list[dict] = []
        self.index = 0
        self._camera = scene.camera

    @property
    def done(self) -> bool:
        return self.index >= len(self.cams)

    def begin(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
        (self.tmp / "images").mkdir(parents=True)

    def step(self) -> None:
        """Render the next camera and save its PNG."""
        cam = self.cams[self.index]
        name = re.sub(r"[^A-Za-z0-9._-]+", "_", cam.name)
        rel = f"images/{self.index:03d}_{name}.png"
        self.scene.camera = cam
        try:
            bpy.ops.render.render()
            with _ImageSettings(self.scene):
                bpy.data.images["Render Result"].save_render(str(self.tmp / rel), scene=self.scene)
        finally:
            self.scene.camera = self._camera
        extra = {"name": cam.name}
        bounds = depth_range(self.scene, cam)
        if bounds:
            extra["near"], extra["far"] = bounds
        self.frames.append({"file_path": rel, "camera": cameras.camera_dict(cam, self.scene),
                            "extra": extra})  # fmt: skip
        self.index += 1

    def transforms_job(self) -> tuple[str, dict]:
        """The worker job that writes ``transforms.json`` into the partial folder."""
        meta = {"generator": "ProSplat capture", "blender": bpy.app.version_string,
                "engine": self.scene.render.engine}  # fmt: skip
        nears = [f["extra"]["near"] for f in self.frames if "near" in f["extra"]]
        if len(nears) == len(self.frames):
            meta["near"] = min(nears)
            meta["far"] = max(f["extra"]["far"] for f in self.frames)
        params = {"path": str(self.tmp / "transforms.json"), "frames": self.frames, "meta": meta}
        return "write_transforms", params

    def finish(self) -> tuple[Path, dict]:
        """Move the finished folder into place; returns it and a posed-images result for
        :func:`.steps.apply_posed_images` (the same cameras, no re-reading needed)."""
        if self.final.exists():  # appeared meanwhile: never merge into it
            self.final = free_folder(self.final)
        os.rename(self.tmp, self.final)
        frames = [
            {
                "name": f["extra"]["name"],
                "image": str(self.final / f["file_path"]),
                "blender": f["camera"],
            }  # fmt: skip
            for f in self.frames
        ]
        result: dict = {"frames": frames}
        nears = [f["extra"].get("near") for f in self.frames]
        if all(n is not None for n in nears):
            result["near"] = min(nears)
            result["far"] = max(f["extra"]["far"] for f in self.frames)
        return self.final, result

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
        self.scene.camera = self._camera
