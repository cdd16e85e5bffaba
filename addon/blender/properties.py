"""Per-scene ProSplat settings (``scene.prosplat``): what the panel's buttons work on."""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from . import cameras, pointcloud
from .operators import RENDER_MODES

VIEW_CHOICES = [
    ("SPREAD", "Spread", "More checked views than the generator takes: farthest-point sampling "
     "over the cameras that see the region of interest (widest coverage)"),
    ("NEAREST", "Nearest Active Camera", "More checked views than the generator takes: the "
     "ones nearest the active camera (best texture for that view)"),
]  # fmt: skip


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
    view_choice: EnumProperty(
        name="Views", items=VIEW_CHOICES, default="SPREAD",
        description="How Reconstruct picks among the checked inputs when there are more than "
        "the generator takes (uncheck inputs to choose them yourself)",
    )  # fmt: skip
    view_index: IntProperty(name="Active Input", default=0, min=0)
    background: FloatVectorProperty(
        name="RGBA Background", subtype="COLOR_GAMMA", size=3, min=0.0, max=1.0,
        default=(1.0, 1.0, 1.0),
        description="Colour that transparent parts of RGBA input images are shown over (white: "
        "the NeRF-synthetic convention; images without alpha are unaffected)",
    )  # fmt: skip
    capture_dir: StringProperty(
        name="Capture Folder", subtype="DIR_PATH", default="//prosplat_capture",
        description="Where Capture Inputs writes posed images (a new folder if it is not empty)",
    )  # fmt: skip
    output_dir: StringProperty(
        name="Output Folder", subtype="DIR_PATH", default="//prosplat_renders",
        description="Where renders go (// = beside the saved .blend; never over existing files "
        "or the input images)",
    )  # fmt: skip
    render_mode: EnumProperty(name="Render", items=RENDER_MODES, default="ACTIVE")
    save_raw: BoolProperty(name="Save Raw", default=False,
                           description="Also save the render before enhancement")  # fmt: skip
    save_depth: BoolProperty(name="Save Depth", default=False,
                             description="Also save the depth (z, scene units) as EXR")  # fmt: skip


CLASSES = (ProSplatSceneSettings,)


def register_props() -> None:
    bpy.types.Scene.prosplat = PointerProperty(type=ProSplatSceneSettings)
    setattr(bpy.types.Object, cameras.USE_PROP, BoolProperty(
        name="Use", default=True,
        description="Offer this input camera to Reconstruct (unchecked: never used)",
    ))  # fmt: skip


def unregister_props() -> None:
    del bpy.types.Scene.prosplat
    delattr(bpy.types.Object, cameras.USE_PROP)
