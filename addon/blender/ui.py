"""The sidebar panel (3D Viewport > N > ProSplat) and the File > Import/Export entries."""

from __future__ import annotations

import importlib.util

import bpy

from . import cameras, modal, pointcloud, runtime, splat_display, steps
from .operators import (
    PROSPLAT_OT_capture_inputs,
    PROSPLAT_OT_export_ply,
    PROSPLAT_OT_import_photos,
    PROSPLAT_OT_import_ply,
    PROSPLAT_OT_import_posed_images,
    PROSPLAT_OT_reconstruct,
    PROSPLAT_OT_render_view,
)


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ProSplat"


class PROSPLAT_PT_main(_Panel, bpy.types.Panel):
    bl_label = "ProSplat"

    def draw(self, context):
        layout = self.layout
        for label, driver in list(modal.ACTIVE.items()):
            layout.progress(factor=driver.job.progress, type="BAR",
                            text=f"{label}: {driver.job.message}")  # fmt: skip
        if not runtime.external_python(context) and importlib.util.find_spec("torch") is None:
            box = layout.box()
            box.label(text="Blender's Python has no torch yet", icon="ERROR")
            box.label(text="Preferences > Add-ons > ProSplat: install it or set a Python")
        p = runtime.prefs(context)
        row = layout.row()
        row.label(text=f"Device: {str(getattr(p, 'device', 'AUTO')).title()}")
        row.label(text="External Python" if runtime.external_python(context) else "In Blender")


class PROSPLAT_UL_views(bpy.types.UIList):
    """The input cameras, each with its *Use* box; a dot marks the views the current
    Gaussians were made from (Reconstruct's own choice, or the artist's)."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_prop, index=0):
        g = context.scene.prosplat.gaussians
        used = set(g.get(steps.VIEWS_PROP, [])) if g is not None else set()
        row = layout.row(align=True)
        row.prop(item, cameras.USE_PROP, text=item.name)
        row.label(text="", icon="LAYER_ACTIVE" if item.name in used else "BLANK1")

    def filter_items(self, context, data, propname):
        objs = getattr(data, propname)
        flags = [self.bitflag_filter_item if o.type == "CAMERA" else 0 for o in objs]
        order = bpy.types.UI_UL_list.sort_items_by_name(objs, "name")
        return flags, order


class PROSPLAT_PT_inputs(_Panel, bpy.types.Panel):
    bl_label = "Inputs"
    bl_parent_id = "PROSPLAT_PT_main"

    def draw(self, context):
        s = context.scene.prosplat
        layout = self.layout
        layout.prop(s, "inputs")
        if s.inputs is not None:
            layout.template_list("PROSPLAT_UL_views", "", s.inputs, "objects", s, "view_index",
                                 rows=4)  # fmt: skip
            targets = steps.targets_of(s.inputs)
            if targets is not None:
                layout.label(text=f"Targets: {targets.name} ({len(targets.objects)})",
                             icon="OUTLINER_COLLECTION")  # fmt: skip
        layout.prop(s, "background")
        col = layout.column(align=True)
        col.operator(PROSPLAT_OT_import_posed_images.bl_idname, icon="IMPORT")
        col.operator(PROSPLAT_OT_import_photos.bl_idname, icon="IMAGE_DATA")
        box = layout.box()
        box.label(text="Synthetic scene: render selected cameras")
        box.prop(s, "capture_dir", text="")
        box.operator(PROSPLAT_OT_capture_inputs.bl_idname, icon="RENDER_STILL")


class PROSPLAT_PT_reconstruct(_Panel, bpy.types.Panel):
    bl_label = "Reconstruct"
    bl_parent_id = "PROSPLAT_PT_main"

    def draw(self, context):
        s, layout = context.scene.prosplat, self.layout
        p = runtime.prefs(context)
        if isinstance(p, bpy.types.AddonPreferences):
            layout.prop(p, "budget")
            layout.prop(p, "merge_flat")
            layout.prop(p, "refine_seconds")
            layout.prop(p, "max_input_size")
        layout.prop(s, "view_choice")
        col = layout.column()
        col.enabled = s.inputs is not None
        col.operator(PROSPLAT_OT_reconstruct.bl_idname, icon="OUTLINER_OB_POINTCLOUD")


class PROSPLAT_PT_gaussians(_Panel, bpy.types.Panel):
    bl_label = "Gaussians"
    bl_parent_id = "PROSPLAT_PT_main"

    def draw(self, context):
        s, layout = context.scene.prosplat, self.layout
        layout.prop(s, "gaussians")
        obj = s.gaussians
        if obj is not None:
            splat_display.draw_settings(layout, obj)
        row = layout.row(align=True)
        row.operator(PROSPLAT_OT_import_ply.bl_idname, text="Import PLY", icon="IMPORT")
        row.operator(PROSPLAT_OT_export_ply.bl_idname, text="Export PLY", icon="EXPORT")


class PROSPLAT_PT_render(_Panel, bpy.types.Panel):
    bl_label = "Render View"
    bl_parent_id = "PROSPLAT_PT_main"

    def draw(self, context):
        s, layout = context.scene.prosplat, self.layout
        layout.prop(s, "render_mode")
        layout.prop(s, "output_dir", text="")
        if not bpy.data.filepath and (not s.output_dir.strip() or s.output_dir.startswith("//")):
            layout.label(text="Save the .blend file or choose a folder", icon="ERROR")
        row = layout.row()
        row.prop(s, "save_raw")
        row.prop(s, "save_depth")
        p = runtime.prefs(context)
        if isinstance(p, bpy.types.AddonPreferences):
            layout.prop(p, "enhance")
            layout.prop(p, "fill_holes")
            row = layout.row()
            row.enabled = p.enhance
            row.prop(p, "distill_steps")
        col = layout.column()
        col.enabled = s.gaussians is not None or pointcloud.is_gaussians(context.active_object)
        col.operator(PROSPLAT_OT_render_view.bl_idname, icon="RENDER_RESULT")


def menu_import(self, context):
    self.layout.operator(PROSPLAT_OT_import_ply.bl_idname, text="Gaussian Splat (.ply, ProSplat)")
    self.layout.operator(PROSPLAT_OT_import_posed_images.bl_idname,
                         text="Posed Images (transforms.json, COLMAP)")  # fmt: skip
    self.layout.operator(PROSPLAT_OT_import_photos.bl_idname,
                         text="Photos or Video, No Poses (ProSplat)")  # fmt: skip


def menu_export(self, context):
    self.layout.operator(PROSPLAT_OT_export_ply.bl_idname, text="Gaussian Splat (.ply, ProSplat)")


CLASSES = (
    PROSPLAT_UL_views,
    PROSPLAT_PT_main,
    PROSPLAT_PT_inputs,
    PROSPLAT_PT_reconstruct,
    PROSPLAT_PT_gaussians,
    PROSPLAT_PT_render,
)
