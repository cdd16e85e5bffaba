"""The capture-like scene ``object_ring`` and rolled cameras / drawn lenses in real renders.

The builder must be seeded like the others and put a ring of eyes round the objects, clear
of them; a render must load; and a rolled camera stored in transforms.json must be the one
Blender rendered: every view's Z pass, unprojected and reprojected into the other views with
the stored cameras, matches their depth, while the level (unrolled) cameras fail that check.
"""

from __future__ import annotations

import math
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from prosplat import Camera
from prosplat.convert.nerfstudio import read_transforms
from prosplat.data import load_scene
from prosplat.data.rigs import draw_lens, draw_roll

pytestmark = pytest.mark.blender
bpy = pytest.importorskip("bpy")

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # `scenes` is not installed

from test_scenes_render import pooled_errors  # noqa: E402

from scenes.builders import (  # noqa: E402
    CAPTURE_SCENES,
    CLEARANCE,
    HARD_SCENES,
    build_scene,
    clear_path,
    clear_scene,
    object_aabbs,
    scene_fingerprint,
)
from scenes.builders import object_ring as ring  # noqa: E402
from scenes.builders.palette import Palette  # noqa: E402
from scenes.builders.query import box_distance  # noqa: E402

SKY_UP = (0.0, 0.0, 1.0)


def test_object_ring_is_a_capture_scene_not_a_hard_one():
    assert "object_ring" in CAPTURE_SCENES and "object_ring" not in HARD_SCENES
    info = build_scene("object_ring", 0)
    assert info.family == "tabletop" and info.tags == ("object_ring",)
    assert ring.LENS_MM[0] <= info.lens_mm <= ring.LENS_MM[1]
    assert info.lens_mm == pytest.approx(draw_lens(0, ring.LENS_MM))


def test_photo128s_lens_range_redraws_the_scenes_own_lens_so_the_framing_holds():
    """``--lens-range`` keeps the ring; the photo128 set's range is the builder's, so the
    renderer's draw is the lens the ring was framed for."""
    from prosplat.data.rigs import parse_lens_range
    from prosplat.data.scene_sets import SCENE_SETS

    options = SCENE_SETS["photo128"].options.split()
    lenses = parse_lens_range(options[options.index("--lens-range") + 1])
    assert lenses == ring.LENS_MM
    for seed in (30000, 30001):
        assert draw_lens(seed, lenses) == build_scene("object_ring", seed).lens_mm


def test_object_ring_builds_the_same_scene_from_a_seed_and_another_from_another():
    a = build_scene("object_ring", 5)
    fa = scene_fingerprint()
    b = build_scene("object_ring", 5)
    fb = scene_fingerprint()
    c = build_scene("object_ring", 6)
    fc = scene_fingerprint()
    assert fa == fb and a == b
    assert fa != fc and a.trajectory != c.trajectory


@pytest.mark.parametrize("seed", range(6))
def test_the_trajectory_is_a_full_ring_round_the_objects_clear_of_them(seed: int):
    info = build_scene("object_ring", seed)
    eyes = np.array([e for e, _ in info.trajectory])
    looks = np.array([t for _, t in info.trajectory])
    centre = looks[0]
    assert np.allclose(looks, centre), "every view looks at the objects' centre"
    props = [(lo, hi) for o, lo, hi in object_aabbs() if not o.name.startswith("support")]
    lo = np.min([b[0] for b in props], axis=0)
    hi = np.max([b[1] for b in props], axis=0)
    assert np.allclose(centre, (lo + hi) / 2)
    offsets = eyes - centre
    distance = np.linalg.norm(offsets, axis=1)
    assert np.allclose(distance, distance[0]), "a ring: one distance all round"
    elevation = np.degrees(np.arcsin(offsets[:, 2] / distance))
    assert elevation.min() >= 5.0 - 1e-9 and elevation.max() <= 57.0 + 1e-9
    azimuth = np.unwrap(np.arctan2(offsets[:, 1], offsets[:, 0]))
    steps = np.diff(azimuth)
    assert np.all(steps * steps[0] > 0), "the ring goes one way round"
    assert abs(azimuth[-1] - azimuth[0] + steps[0]) == pytest.approx(2 * math.pi)
    for obj, blo, bhi in object_aabbs():
        gap = box_distance(eyes, blo, bhi).min()
        assert gap >= CLEARANCE, f"an eye is {gap:.2f} m from {obj.name}"
    # the objects fill at most the drawn fraction of the frame (less where moved out)
    fill = np.max(hi - lo) * info.lens_mm / 36.0 / distance[0]
    assert 0.15 < fill <= ring.FILL[1] + 1e-9
    roots = {o.name.split("_")[0] for o in bpy.context.scene.objects if o.name.startswith("obj")}
    assert 1 <= len(roots) <= 3


@pytest.mark.parametrize("seed", range(6))
def test_clear_path_never_has_to_remove_anything(seed: int):
    """The ring keeps its own gap, so ``build_scene``'s ``clear_path`` finds nothing to do."""
    clear_scene()
    layout = random.Random(f"object_ring/layout/{seed}")
    pal = Palette(random.Random(f"materials/{seed}"), np.random.default_rng([seed, 1]))
    built = ring.build(layout, pal, seed)
    assert clear_path(built.eyes, CLEARANCE) == []


def render(out: Path, seed: int, *extra: str, size: int = 32) -> Path:
    """One object_ring scene through ``prosplat scenes render`` (CLI, worker command line and
    ``render_scene``): ``size`` px, 2 inputs + 2 targets, 4 samples."""
    cmd = [sys.executable, "-m", "prosplat", "scenes", "render", "--out", str(out)]
    cmd += ["--scene", "object_ring", "--seed", str(seed), "--count", "1", "--workers", "1"]
    cmd += ["--size", str(size), "--inputs", "2", "--targets", "2", "--samples", "4", *extra]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    return out / f"object_ring_{seed:06d}"


ROLL, LENSES, SEED = 30.0, (30.0, 60.0), 4
ROLLED_SIZE = 48  # at 32 px the objects' silhouettes leave too few pixels for the depth check


@pytest.fixture(scope="module")
def rolled(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rolled")
    lenses = f"{LENSES[0]}-{LENSES[1]}"
    return render(out, SEED, "--roll", str(ROLL), "--lens-range", lenses, size=ROLLED_SIZE)


def _frames(folder: Path) -> list[dict]:
    """Each frame's extra keys in transforms.json (split, trajectory_index, roll_deg...)."""
    return [f.extra for f in read_transforms(folder).frames]


def _level_cameras(folder: Path) -> list[Camera]:
    """The cameras the scene's trajectory gives without roll, at the stored focal length."""
    sc = load_scene(folder)
    info = build_scene("object_ring", SEED)
    cams = []
    for frame, cam in zip(_frames(folder), sc.cameras):
        eye, look = info.trajectory[frame["trajectory_index"]]
        cams.append(Camera.look_at(eye, look, SKY_UP, cam.fx, cam.width, cam.height))
    return cams


def test_a_rendered_object_ring_loads_and_records_its_roll_and_lens(rolled):
    sc = load_scene(rolled)
    assert sc.images.shape == (4, 3, ROLLED_SIZE, ROLLED_SIZE) and len(sc.input_indices) == 2
    assert sc.meta["name"] == "object_ring" and sc.meta["tags"] == ["object_ring"]
    assert (sc.depths > 0).any() and torch.isfinite(sc.images).all()
    lens = sc.meta["renderer"]["lens_mm"]
    assert LENSES[0] <= lens <= LENSES[1] and lens == pytest.approx(draw_lens(SEED, LENSES))
    assert sc.meta["renderer"]["lens_range_mm"] == list(LENSES)
    for cam in sc.cameras:
        assert cam.fx == pytest.approx(lens / 36.0 * ROLLED_SIZE, rel=1e-9)
    rolls = [f["roll_deg"] for f in _frames(rolled)]
    assert rolls == [draw_roll(SEED, v, ROLL) for v in range(4)]
    assert all(abs(r) <= ROLL for r in rolls) and len(set(rolls)) == 4


def test_the_stored_camera_is_the_level_one_rolled_by_the_drawn_angle(rolled):
    sc = load_scene(rolled)
    for frame, cam, level in zip(_frames(rolled), sc.cameras, _level_cameras(rolled)):
        assert torch.allclose(cam.center, level.center, atol=1e-6)
        assert torch.allclose(cam.forward, level.forward, atol=1e-6)
        up, right = -level.R[1], level.R[0]
        stored_up = -cam.R[1]
        angle = math.degrees(math.atan2(float(-stored_up @ right), float(stored_up @ up)))
        assert angle == pytest.approx(frame["roll_deg"], abs=1e-4)


def test_a_rolled_scenes_depth_reprojects_between_views_and_level_cameras_fail(rolled):
    """Blender rendered the stored rolled cameras: the Z passes agree across views through
    them, and not through the same cameras without their roll."""
    sc = load_scene(rolled)
    rel, _, _, pairs = pooled_errors(sc, sc.cameras)
    assert pairs >= 2
    assert rel.median() < 0.002 and (rel < 0.01).float().mean() > 0.9
    bad = pooled_errors(sc, _level_cameras(rolled))[0]
    assert bad.median() > 5 * rel.median() and bad.median() > 0.002


def test_roll_0_and_no_lens_range_leave_the_cameras_as_they_were(rolled, tmp_path):
    name = f"object_ring_{SEED:06d}"
    plain = load_scene(render(tmp_path / "plain", SEED))
    zero = load_scene(render(tmp_path / "zero", SEED, "--roll", "0"))
    info = build_scene("object_ring", SEED)
    for a, b, frame in zip(plain.cameras, zero.cameras, _frames(tmp_path / "plain" / name)):
        assert torch.equal(a.world_to_cam, b.world_to_cam) and torch.equal(a.K, b.K)
        eye, look = info.trajectory[frame["trajectory_index"]]
        level = Camera.look_at(eye, look, SKY_UP, info.lens_mm / 36.0 * 32, 32, 32)
        assert torch.allclose(a.world_to_cam, level.world_to_cam, atol=1e-9)
        assert a.fx == pytest.approx(level.fx, rel=1e-12)
        assert "roll_deg" not in frame
    assert torch.equal(plain.depths, zero.depths)
    assert (plain.images - zero.images).abs().max() <= 1 / 255 + 1e-6
    assert "lens_mm" not in plain.meta["renderer"] and "max_roll_deg" not in plain.meta["renderer"]
