"""Camera conversions: Blender, nerfstudio/instant-ngp ``transforms.json`` and COLMAP
(text and binary), and lens distortion (:mod:`prosplat.convert.distortion`).

Every reader returns :class:`prosplat.Camera` (OpenCV axes, pixel centres at +0.5) and every
writer takes it, so the rest of ProSplat never sees another convention. The Blender side is
pure math; the add-on feeds it values read from ``bpy``.
"""

from prosplat.convert.blender import (
    OPENGL_TO_OPENCV,
    BlenderCameraParams,
    blender_from_camera,
    blender_render_size,
    blender_to_opencv_c2w,
    camera_from_blender,
    opencv_to_blender_c2w,
)
from prosplat.convert.colmap import (
    ColmapImage,
    ColmapModel,
    read_colmap_model,
    read_colmap_text,
    write_colmap_text,
)
from prosplat.convert.distortion import Distortion, undistort_view
from prosplat.convert.nerfstudio import Frame, TransformsFile, read_transforms, write_transforms

__all__ = [
    "OPENGL_TO_OPENCV",
    "BlenderCameraParams",
    "ColmapImage",
    "ColmapModel",
    "Distortion",
    "Frame",
    "TransformsFile",
    "blender_from_camera",
    "blender_render_size",
    "blender_to_opencv_c2w",
    "camera_from_blender",
    "opencv_to_blender_c2w",
    "undistort_view",
    "read_colmap_model",
    "read_colmap_text",
    "read_transforms",
    "write_colmap_text",
    "write_transforms",
]
