"""Per-scene ProSplat settings (``scene.prosplat``): what the panel's buttons work on."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, PointerProperty, StringProperty

from . import pointcloud
from .operators import RENDER_MODES


def _is_gaussians(self, obj) -> bool:
    return pointcloud.is_gaussians(obj)


class ProSplatSceneSettings(bpy.types.PropertyGroup):
    inputs: PointerProperty(
        name="Inputs", type=bpy.types.Collection,
        description="The collection of input cameras (each showing its image)",
    )  # fmt: skip
    gaussians: PointerProperty(
        name="Gaussians", type=bpy.types.Object, poll=_is_gaussians,
        description="The Gaussian point cloud to render",
    )  # fmt: skip
    capture_dir: StringProperty(
        name="Capture Folder", subtype="DIR_PATH", default="//prosplat/capture",
        description="Where Capture Inputs writes posed images (a new folder if it is not empty)",
    )  # fmt: skip
    output_dir: StringProperty(
        name="Output Folder", subtype="DIR_PATH", default="//prosplat/renders",
        description="Where renders go (never over existing files or the input images)",
    )  # fmt: skip
    render_mode: EnumProperty(name="Render", items=RENDER_MODES, default="ACTIVE")
    save_raw: BoolProperty(name="Save Raw", default=False,
                           description="Also save the render before enhancement")  # fmt: skip
    save_depth: BoolProperty(name="Save Depth", default=False,
                             description="Also save the depth (z, scene units) as EXR")  # fmt: skip


CLASSES = (ProSplatSceneSettings,)


def register_props() -> None:
    bpy.types.Scene.prosplat = PointerProperty(type=ProSplatSceneSettings)


def unregister_props() -> None:
    del bpy.types.Scene.prosplat
