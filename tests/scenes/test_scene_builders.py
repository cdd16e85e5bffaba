"""Seeded procedural Blender scenes (``scenes.builders``).

The renderer and the training data rely on: every name builds quickly; a seed fixes the
scene exactly (geometry, materials, trajectory) and different seeds differ; trajectories
are long, smooth and ordered; cameras never sit in or right next to an object and always
look at geometry; and a real Cycles render of a view is neither black nor NaN.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # `scenes` is not installed

from mathutils import Vector  # noqa: E402

from scenes.builders import (  # noqa: E402
    CLEARANCE,
    FAMILIES,
    HARD_SCENES,
    SceneInfo,
    build_scene,
    family_for_seed,
    object_aabbs,
    scene_bounds,
    scene_fingerprint,
)
from scenes.builders.lights import look_rotation  # noqa: E402
from scenes.builders.primitives import ROLE_KEY  # noqa: E402
from scenes.builders.query import box_distance, world_vertices  # noqa: E402

ALL = FAMILIES + HARD_SCENES
CASES = [(name, seed) for name in ALL for seed in (0, 1)]


def _build(name: str, seed: int) -> tuple[SceneInfo, float]:
    t0 = time.perf_counter()
    info = build_scene(name, seed)
    return info, time.perf_counter() - t0


def _eyes_and_dirs(info: SceneInfo) -> tuple[np.ndarray, np.ndarray]:
    eyes = np.array([e for e, _ in info.trajectory])
    look = np.array([t for _, t in info.trajectory]) - eyes
    return eyes, look / np.linalg.norm(look, axis=1, keepdims=True)


@pytest.mark.parametrize(("name", "seed"), CASES)
def test_builds_quickly_with_a_valid_info(name: str, seed: int) -> None:
    info, seconds = _build(name, seed)
    assert seconds < 2.0, f"{name} seed {seed} took {seconds:.2f} s to build"
    assert info.name == name and info.seed == seed and info.family in FAMILIES
    if name in FAMILIES:
        assert info.family == name and info.tags == ()
    else:
        assert name in info.tags
    assert len(info.trajectory) >= 48
    assert 15.0 <= info.lens_mm <= 60.0
    lo, hi = np.array(info.bounds_min), np.array(info.bounds_max)
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)
    assert np.all(np.isfinite(np.array(info.trajectory)))
    scene = bpy.context.scene
    assert not any(o.type == "CAMERA" for o in scene.objects), "builders must not add cameras"
    assert any(o.type == "LIGHT" for o in scene.objects) and scene.world is not None
    faces = 0
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for o in scene.objects:
        if o.type == "MESH":
            faces += len(o.evaluated_get(depsgraph).data.polygons)
    assert faces < 50_000, f"{name}: {faces} faces is too heavy for quick CPU renders"


@pytest.mark.parametrize("name", ALL)
def test_same_seed_same_scene_other_seed_differs(name: str) -> None:
    a, _ = _build(name, 5)
    fa = scene_fingerprint()
    b, _ = _build(name, 5)
    fb = scene_fingerprint()
    c, _ = _build(name, 6)
    fc = scene_fingerprint()
    assert fa == fb and a == b
    assert fa != fc and a.trajectory != c.trajectory


def test_fingerprint_sees_material_settings() -> None:
    build_scene("room", 0)
    before = scene_fingerprint()
    mat = next(m for m in bpy.data.materials if m.node_tree is not None)
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Roughness"].default_value = 0.123
    assert scene_fingerprint() != before


@pytest.mark.parametrize(("name", "seed"), CASES)
def test_trajectory_is_smooth_and_clear_of_objects(name: str, seed: int) -> None:
    info, _ = _build(name, seed)
    eyes, dirs = _eyes_and_dirs(info)
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert steps.min() > 0 and steps.max() < 3 * np.median(steps), "poses are not evenly spaced"
    turns = np.degrees(np.arccos(np.clip(np.sum(dirs[1:] * dirs[:-1], axis=1), -1, 1)))
    assert turns.max() < 35.0, f"view direction jumps by {turns.max():.1f} degrees"
    for obj, lo, hi in object_aabbs():
        if obj.get(ROLE_KEY) == "shell":
            continue
        inside = np.all((eyes >= lo) & (eyes <= hi), axis=1)
        assert not inside.any(), f"an eye is inside the bounding box of {obj.name}"
        gap = box_distance(eyes, lo, hi).min()
        assert gap >= CLEARANCE - 1e-6, f"an eye is {gap:.2f} m from {obj.name}"
    if info.family == "room":
        lo, hi = np.array(info.bounds_min), np.array(info.bounds_max)
        assert np.all((eyes > lo) & (eyes < hi))


@pytest.mark.parametrize(("name", "seed"), CASES)
def test_every_view_looks_at_geometry(name: str, seed: int) -> None:
    # Required for room and tabletop; open scenes pitch down so the ground is always hit.
    info, _ = _build(name, seed)
    scene, depsgraph = bpy.context.scene, bpy.context.evaluated_depsgraph_get()
    eyes, dirs = _eyes_and_dirs(info)
    misses = [
        i
        for i, (e, d) in enumerate(zip(eyes, dirs))
        if not scene.ray_cast(depsgraph, Vector(e), Vector(d))[0]
    ]
    assert not misses, f"poses {misses} look at empty sky"


def test_scene_bounds_cover_all_geometry() -> None:
    info = build_scene("tabletop", 2)
    lo, hi = np.array(info.bounds_min), np.array(info.bounds_max)
    for _, olo, ohi in object_aabbs():
        assert np.all(olo >= lo - 1e-6) and np.all(ohi <= hi + 1e-6)
    assert (tuple(lo), tuple(hi)) == scene_bounds()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with pytest.raises(ValueError, match="no geometry"):
        scene_bounds()


def test_family_for_seed_and_unknown_names() -> None:
    assert [family_for_seed(s) for s in range(6)] == list(FAMILIES) * 2
    with pytest.raises(ValueError, match="unknown scene"):
        build_scene("castle", 0)


def test_textureless_is_the_room_layout_without_textures() -> None:
    def geometry() -> dict[str, np.ndarray]:
        dg = bpy.context.evaluated_depsgraph_get()
        return {
            o.name: world_vertices(o.evaluated_get(dg))
            for o in bpy.context.scene.objects
            if o.type == "MESH"
        }

    build_scene("room", 3)
    room = geometry()
    build_scene("textureless", 3)
    plain = geometry()
    assert room.keys() == plain.keys()
    assert all(np.allclose(room[k], plain[k]) for k in room)
    for mat in bpy.data.materials:
        kinds = {n.bl_idname for n in mat.node_tree.nodes}
        assert not any(
            k.startswith("ShaderNodeTex") and k != "ShaderNodeTexCoord" for k in kinds
        ), mat.name


def _node_kinds() -> set[str]:
    return {n.bl_idname for m in bpy.data.materials for n in m.node_tree.nodes}


def test_hard_scenes_have_their_difficulty() -> None:
    build_scene("repeated_pattern", 0)
    assert {"ShaderNodeTexBrick", "ShaderNodeTexChecker"} <= _node_kinds()
    assert sum(m.type == "ARRAY" for o in bpy.context.scene.objects for m in o.modifiers) >= 6

    build_scene("specular", 0)
    mirrors = [
        n
        for m in bpy.data.materials
        for n in m.node_tree.nodes
        if n.bl_idname == "ShaderNodeBsdfPrincipled"
        and n.inputs["Metallic"].default_value > 0.9
        and n.inputs["Roughness"].default_value < 0.1
    ]
    assert len(mirrors) >= 2

    build_scene("thin_structures", 0)
    thin = [o for o in bpy.context.scene.objects if o.type == "CURVE" and o.data.bevel_depth < 0.01]
    assert len(thin) >= 8

    info = build_scene("near_far", 0)
    eyes, _ = _eyes_and_dirs(info)
    boxes = object_aabbs()
    nearest = min(
        box_distance(eyes, lo, hi).min() for o, lo, hi in boxes if o.get(ROLE_KEY) == "prop"
    )
    farthest = max(np.linalg.norm((lo + hi) / 2) for _, lo, hi in boxes)
    assert nearest < 0.75 and farthest > 80

    info = build_scene("inside_outside", 0)
    eyes, _ = _eyes_and_dirs(info)
    floor = bpy.context.scene.objects["house_floor"]
    flo, fhi = (np.array(v) for v in next((lo, hi) for o, lo, hi in object_aabbs() if o == floor))
    inside = np.all((eyes[:, :2] > flo[:2]) & (eyes[:, :2] < fhi[:2]), axis=1)
    assert not inside[0] and inside[-1]


@pytest.mark.parametrize("family", FAMILIES)
def test_tiny_cycles_render_is_lit_and_finite(family: str, tmp_path: Path) -> None:
    info = build_scene(family, 0)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("test_cam")
    cam_data.lens, cam_data.sensor_width, cam_data.sensor_fit = info.lens_mm, 36.0, "HORIZONTAL"
    cam_data.clip_end = 1000.0
    cam = bpy.data.objects.new("test_cam", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    eye, target = info.trajectory[0]
    cam.location, cam.rotation_euler = eye, look_rotation(eye, target)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "view.exr")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - t0
    img = bpy.data.images.load(str(tmp_path / "view.exr"))
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    rgb = px.reshape(32, 32, -1)[..., :3]
    assert np.all(np.isfinite(rgb)), "render has NaN/inf"
    assert 0.02 < float(rgb.mean()) < 5.0, f"mean radiance {rgb.mean():.3f}: black or blown out"
    assert float(rgb.std()) > 1e-3, "render is flat"
    assert seconds < 10.0, f"tiny render took {seconds:.1f} s"
