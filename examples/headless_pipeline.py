"""ProSplat without the UI: build a small scene, capture inputs, reconstruct, render, export.

Runs the same way in both headless setups::

    python examples/headless_pipeline.py --out out/example          # the bpy module (pip)
    blender -b -P examples/headless_pipeline.py -- --out out/example  # Blender itself

With ``--transforms PATH`` it imports posed images (transforms.json or COLMAP) instead of
building and capturing a scene, and renders the first camera. The add-on is used from the
installed extension when Blender has it, else from this repository's ``addon/`` folder.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
import time
from pathlib import Path

import bpy

REPO = Path(__file__).resolve().parents[1]


def load_addon():
    """The add-on package: the installed extension if enabled, else the repository's."""
    for name in ("bl_ext.user_default.prosplat", "bl_ext.blender_org.prosplat"):
        if name in bpy.context.preferences.addons:
            return importlib.import_module(name)
    sys.path.insert(0, str(REPO))
    addon = importlib.import_module("addon")
    if not hasattr(bpy.types.Scene, "prosplat"):
        addon.register()
    return addon


def look_at(obj, target) -> None:
    from mathutils import Vector

    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def build_scene(size: int):
    """A floor, three coloured shapes, a sun and four cameras on an arc; returns (inputs, target)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 16
    scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    bpy.ops.mesh.primitive_plane_add(size=8)
    shapes = [((-0.8, 0.0, 0.5), (0.8, 0.2, 0.2)), ((0.7, 0.4, 0.45), (0.2, 0.7, 0.3)),
              ((0.1, -0.9, 0.4), (0.2, 0.3, 0.9))]  # fmt: skip
    for i, (loc, rgb) in enumerate(shapes):
        if i % 2 == 0:
            bpy.ops.mesh.primitive_cube_add(size=0.8, location=loc)
        else:
            bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=loc)
        mat = bpy.data.materials.new(f"m{i}")
        mat.diffuse_color = (*rgb, 1.0)
        if mat.node_tree is not None:
            mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*rgb, 1.0)
        bpy.context.object.data.materials.append(mat)
    bpy.ops.object.light_add(type="SUN", rotation=(0.6, 0.2, 0.5))
    cams = []
    for i, angle in enumerate([-50, -10, 30, 10]):
        data = bpy.data.cameras.new(f"cam{i}")
        obj = bpy.data.objects.new("target" if i == 3 else f"input{i}", data)
        scene.collection.objects.link(obj)
        a = math.radians(angle)
        obj.location = (4.5 * math.sin(a), -4.5 * math.cos(a), 2.5)
        look_at(obj, (0, 0, 0.3))
        cams.append(obj)
    scene.camera = cams[3]
    bpy.context.view_layer.update()
    return cams[:3], cams[3]


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/example"))
    ap.add_argument("--transforms", help="posed images to import instead of building a scene")
    ap.add_argument("--size", type=int, default=64, help="render size of the built scene")
    args = ap.parse_args(argv)
    api = importlib.import_module(f"{load_addon().__name__}.blender.api")
    t0 = time.perf_counter()
    if args.transforms:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        load_addon()
        inputs = api.import_posed_images(args.transforms)
        # a scene folder's own target frames, else an input view (a sanity check)
        targets = inputs.get("prosplat_targets") or inputs
        target = sorted(targets.objects, key=lambda o: o.name)[0]
    else:
        cams, target = build_scene(args.size)
        folder, inputs = api.capture_inputs(cams, args.out / "capture")
        print(f"captured {len(cams)} views into {folder} ({time.perf_counter() - t0:.1f} s)")
    gaussians = api.reconstruct(inputs)
    print(
        f"reconstructed {len(gaussians.data.vertices):,} Gaussians ({time.perf_counter() - t0:.1f} s)"
    )
    result = api.render_views(
        gaussians, [target], args.out / "renders", inputs=inputs, save_depth=True
    )
    for view in result["views"]:
        print(f"rendered {view['name']} -> {view['image']} (reference: {view['reference_name']})")
    for warning in result["warnings"]:
        print(f"warning: {warning}")
    ply, k = args.out / "gaussians.ply", 1
    while ply.exists():  # export never overwrites: pick a free name
        k += 1
        ply = args.out / f"gaussians-{k}.ply"
    api.export_ply(gaussians, ply)
    print(f"wrote {ply} ({time.perf_counter() - t0:.1f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]))
