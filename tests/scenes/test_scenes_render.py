"""Blender renders that prove cameras, depth and images agree (runs Cycles through bpy).

The geometry test unprojects every input view's Z-pass depth, reprojects it into the other
views, and checks depth and colour where the point is visible there. A perturbed camera
must fail the same check, so the test can tell right from wrong.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from prosplat import Camera
from prosplat.data import load_scene

pytestmark = pytest.mark.blender
pytest.importorskip("bpy")

SIZE = 64


def render(out: Path, name: str, seed: int, *extra: str) -> Path:
    cmd = [
        sys.executable,
        "-m",
        "scenes.render",
        "--name",
        name,
        "--seed",
        str(seed),
        "--out",
        str(out),
        "--size",
        str(SIZE),
        "--inputs",
        "2",
        "--targets",
        "2",
        "--samples",
        "32",
        *extra,
    ]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    return out / f"{name}_{seed:06d}"


@pytest.fixture(scope="module")
def tabletop(tmp_path_factory) -> tuple[Path, float]:
    out = tmp_path_factory.mktemp("scenes")
    t0 = time.perf_counter()
    folder = render(out, "tabletop", 5)
    return folder, time.perf_counter() - t0


def reprojection_errors(src: Camera, src_depth, src_img, dst: Camera, dst_depth, dst_img):
    """Depth relative error and colour error of src's pixels that dst sees (not occluded)."""
    h, w = dst_depth.shape  # dst's image bounds the reprojected pixels
    d = src_depth.double()
    # Skip depth discontinuities: the Z pass is one sample per pixel, colours are averaged.
    pad = F.pad(d[None, None], (1, 1, 1, 1), mode="replicate")[0, 0]
    neigh = torch.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    smooth = ((neigh - d).abs() <= 0.03 * d).all(0)
    valid = (d > 0) & smooth
    uv = src.pixel_centers(torch.float64)[valid]
    pts = src.unproject(uv, d[valid])
    uv2, z2 = dst.project(pts)
    inside = (
        (z2 > 0) & (uv2[:, 0] >= 1) & (uv2[:, 0] < w - 1) & (uv2[:, 1] >= 1) & (uv2[:, 1] < h - 1)
    )
    # Bilinear lookup between dst's pixel centres (grid_sample, align_corners=False, puts
    # pixel centres at +0.5 like our cameras); nearest-pixel lookup on a grazing floor would
    # be off by half a pixel's depth change.
    grid = (uv2[inside] / torch.tensor([w, h], dtype=torch.float64)) * 2 - 1

    def lookup(img):
        return F.grid_sample(img[None].double(), grid[None, None], align_corners=False)[0, :, 0]

    z_dst = lookup(dst_depth[None])[0]
    near = lookup(dst_depth[None].clamp_min(0).eq(0).double())[0] == 0  # no sky among the 4 taps
    rel = (z_dst - z2[inside]).abs() / z2[inside]
    visible = (rel < 0.05) & near
    sampled = lookup(dst_img)[:, visible].T  # [V,3]
    src_colour = src_img.double()[:, valid].T[inside][visible]  # [V,3]
    colour = (sampled - src_colour).abs().mean(1)
    # Control: the same colours paired with the wrong points. Textures are high-frequency at
    # test resolutions, so colour is judged against this rather than an absolute bound.
    shuffled = sampled[torch.randperm(len(sampled), generator=torch.Generator().manual_seed(0))]
    control = (shuffled - src_colour).abs().mean(1)
    return rel, visible, colour, control


def pooled_errors(sc, cameras):
    """Depth relative errors and colour errors of all view pairs that overlap, pooled."""
    rels, colours, controls, pairs = [], [], [], 0
    for i in range(len(sc)):
        for j in range(len(sc)):
            if i == j:
                continue
            rel, visible, colour, control = reprojection_errors(
                cameras[i], sc.depths[i], sc.images[i], cameras[j], sc.depths[j], sc.images[j]
            )
            if visible.sum() < 50:
                continue  # these two views barely overlap
            pairs += 1
            rels.append(rel[visible])
            colours.append(colour)
            controls.append(control)
    return torch.cat(rels), torch.cat(colours), torch.cat(controls), pairs


def test_depth_and_colour_reproject_between_views(tabletop):
    folder, seconds = tabletop
    assert seconds < 60, f"tiny scene took {seconds:.1f}s"
    sc = load_scene(folder)
    assert sc.images.shape == (4, 3, SIZE, SIZE) and len(sc.input_indices) == 2
    assert (sc.depths > 0).float().mean() > 0.5  # a tabletop view mostly sees geometry
    rel, colour, control, pairs = pooled_errors(sc, sc.cameras)
    assert pairs >= 6
    assert rel.median() < 0.002  # reprojected depth agrees with the other view's Z pass
    assert (rel < 0.01).float().mean() > 0.9
    # Colours agree far better than mismatched pairs do. Not to zero: at 64 px the procedural
    # textures alias differently per view, and glossy surfaces change with the viewpoint.
    assert colour.median() < 0.08 and colour.median() < 0.6 * control.median()


def test_a_half_pixel_convention_error_fails_the_same_check(tabletop):
    """Principal point at (W-1)/2 instead of W/2, the classic pixel-centre slip: caught."""
    sc = load_scene(tabletop[0])
    shifted = []
    for k, cam in enumerate(sc.cameras):
        K = cam.K.clone()
        K[:2, 2] -= 0.5 if k % 2 else 0.0
        shifted.append(Camera(K, cam.world_to_cam, cam.width, cam.height))
    rel_ok = pooled_errors(sc, sc.cameras)[0]
    rel_bad = pooled_errors(sc, shifted)[0]
    assert rel_bad.median() > 5 * rel_ok.median() and rel_bad.median() > 0.002


def test_same_seed_renders_the_same_files(tabletop, tmp_path):
    again = render(tmp_path, "tabletop", 5)
    a, b = load_scene(tabletop[0]), load_scene(again)
    assert (a.images - b.images).abs().max() <= 1 / 255 + 1e-6
    assert torch.equal(a.depths, b.depths)
    assert [c.world_to_cam.tolist() for c in a.cameras] == [
        c.world_to_cam.tolist() for c in b.cameras
    ]


def test_transforms_json_records_scene_facts(tabletop):
    sc = load_scene(tabletop[0])
    m = sc.meta
    assert m["family"] == "tabletop" and m["seed"] == 5 and m["split_set"] == "train"
    assert 0 < m["near"] < m["far"]
    assert len(m["input_overlap"]) == 2 and 0 <= m["mean_input_overlap"] <= 1
    assert m["renderer"]["view_transform"] == "Standard"
    assert {k for k in sc.target_kinds if k} <= {"interpolation", "extrapolation"}
    assert float(sc.near.min()) == pytest.approx(float(sc.depths[sc.depths > 0].min()), rel=1e-6)


def test_cli_renders_in_parallel_and_skips_finished_scenes(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "prosplat",
        "scenes",
        "render",
        "--seed",
        "0",
        "--count",
        "2",
        "--out",
        str(tmp_path),
        "--size",
        "16",
        "--samples",
        "2",
        "--inputs",
        "2",
        "--targets",
        "1",
        "--workers",
        "2",
    ]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    folders = sorted(p.name for p in tmp_path.iterdir())
    assert folders == ["room_000000", "tabletop_000001"]
    stamp = (tmp_path / "room_000000" / "transforms.json").stat().st_mtime_ns
    (tmp_path / ".open_000002.partial-999999999").mkdir()  # leftover of a killed run
    res = subprocess.run(cmd[:8] + ["3"] + cmd[9:], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "2 of 3 scenes already rendered" in res.stdout
    assert (tmp_path / "room_000000" / "transforms.json").stat().st_mtime_ns == stamp
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "open_000002",
        "room_000000",
        "tabletop_000001",
    ]


def _cli_render(out: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "prosplat", "scenes", "render", "--out", str(out), "--size"]
    cmd += ["16", "--samples", "2", "--inputs", "2", "--targets", "1", *extra]
    return subprocess.run(cmd, capture_output=True, text=True)


def test_one_worker_renders_scene_after_scene_as_fresh_processes_do(tmp_path):
    """A long-lived worker renders its second scene as a process of its own would (each scene
    starts from Blender's factory settings): the same images up to 1/255 and the same depth."""
    res = _cli_render(tmp_path / "batch", "--seed", "0", "--count", "2", "--workers", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    res = _cli_render(tmp_path / "fresh", "--seed", "1", "--count", "1", "--workers", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    a = load_scene(tmp_path / "batch" / "tabletop_000001")
    b = load_scene(tmp_path / "fresh" / "tabletop_000001")
    assert (a.images - b.images).abs().max() <= 1 / 255 + 1e-6
    assert torch.equal(a.depths, b.depths)


def test_fast_denoiser_is_used_recorded_and_close_to_the_default(tmp_path):
    """--denoise-quality fast reaches Cycles (the colour differs from the default denoiser's),
    is recorded in transforms.json, leaves depth alone and stays close to the default's image."""
    args = ("--seed", "2", "--count", "1", "--workers", "1", "--denoise")
    res = _cli_render(tmp_path / "high", *args)
    assert res.returncode == 0, res.stderr[-3000:]
    res = _cli_render(tmp_path / "fast", *args, "--denoise-quality", "fast")
    assert res.returncode == 0, res.stderr[-3000:]
    a, b = (load_scene(tmp_path / q / "open_000002") for q in ("high", "fast"))
    assert a.meta["renderer"]["denoise_quality"] == "high"
    assert b.meta["renderer"]["denoise_quality"] == "fast"
    assert torch.equal(a.depths, b.depths)
    assert (a.images - b.images).abs().max() > 2 / 255
    psnr = -10 * torch.log10(F.mse_loss(a.images, b.images))
    assert psnr > 25, psnr


def test_a_failing_scene_is_reported_and_the_worker_goes_on(tmp_path):
    """Every failing scene is named with its error and counted; the run exits 1, writes no
    folder for it, and a worker that fails one scene still takes the next."""
    res = _cli_render(tmp_path, "--seed", "0", "--count", "2", "--workers", "1", "--scene", "nope")
    assert res.returncode == 1
    assert "scene nope seed 0 failed" in res.stderr and "scene nope seed 1 failed" in res.stderr
    assert "room" in res.stderr  # the builder's error lists the valid names
    assert "rendered 0 scenes" in res.stdout and "2 failed" in res.stdout
    assert not any(p.name.startswith("nope") for p in tmp_path.iterdir())


def test_scenes_list_reports_split_family_and_overlap(tabletop):
    out = tabletop[0].parent
    res = subprocess.run(
        [sys.executable, "-m", "prosplat", "scenes", "list", "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr
    row = next(line for line in res.stdout.splitlines() if line.startswith("| tabletop_000005"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    overlap = load_scene(tabletop[0]).meta["mean_input_overlap"]
    assert cells[1:5] == ["train", "tabletop", "-", "2"] and float(cells[6]) == round(overlap, 2)


def test_a_scene_published_meanwhile_by_another_run_is_kept(tmp_path):
    """Two runs of one seed side by side: the second to finish keeps the first's folder and
    drops its own copy instead of failing (the rename onto a non-empty folder raised and
    stopped a render of rounds); a folder there that is no finished scene still raises."""
    from scenes.render import _publish

    def scene(path: Path, text: str) -> Path:
        path.mkdir()
        (path / "transforms.json").write_text(text)
        return path

    final = tmp_path / "open_000001"
    _publish(scene(tmp_path / ".open_000001.partial-1", "first"), final)
    assert (final / "transforms.json").read_text() == "first"
    mine = scene(tmp_path / ".open_000001.partial-2", "second")
    _publish(mine, final)
    assert (final / "transforms.json").read_text() == "first" and not mine.exists()

    broken = tmp_path / "open_000002"
    (broken / "images").mkdir(parents=True)
    with pytest.raises(OSError):
        _publish(scene(tmp_path / ".open_000002.partial-3", "third"), broken)


WIDE = (96, 54)  # 16:9


@pytest.fixture(scope="module")
def wide(tmp_path_factory) -> tuple[Path, list[str]]:
    """A 16:9 tabletop scene rendered through ``prosplat scenes render --width --height`` (the
    CLI, its worker's command line and ``render_scene``); returns the folder and the command."""
    out = tmp_path_factory.mktemp("wide")
    cmd = [sys.executable, "-m", "prosplat", "scenes", "render", "--out", str(out)]
    cmd += ["--scene", "tabletop", "--seed", "7", "--count", "1", "--workers", "1"]
    cmd += ["--width", str(WIDE[0]), "--height", str(WIDE[1]), "--inputs", "2", "--targets", "1"]
    cmd += ["--samples", "4"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    return out / "tabletop_000007", cmd


def test_a_16_9_scene_has_w_by_h_images_and_centred_square_pixel_cameras(wide):
    from PIL import Image

    from scenes.builders import build_scene

    w, h = WIDE
    sc = load_scene(wide[0])
    assert sc.images.shape == (3, 3, h, w) and sc.depths.shape == (3, h, w)
    for v in range(3):
        with Image.open(wide[0] / "images" / f"{v:03d}.png") as im:
            assert im.size == (w, h)
    # Blender's 36 mm sensor (fit AUTO) spans the longer side: fx = fy = lens / 36 * max(W, H)
    fx = build_scene("tabletop", 7).lens_mm / 36.0 * max(w, h)
    for cam in sc.cameras:
        assert (cam.width, cam.height) == (w, h)
        assert cam.fx == pytest.approx(fx, rel=1e-9) and cam.fy == cam.fx
        assert (float(cam.K[0, 2]), float(cam.K[1, 2])) == (w / 2, h / 2)
    assert len(sc.meta["input_overlap"]) == 2 and 0 < sc.meta["mean_input_overlap"] <= 1


def test_a_16_9_scenes_depth_reprojects_between_views_and_a_square_focal_fails(wide):
    """Blender's projection agrees with the cameras: every view's Z pass, unprojected and
    reprojected into the others, matches their depth. The focal length of the shorter side
    (Blender's sensor fit misread) fails the same check."""
    sc = load_scene(wide[0])
    rel, _, _, pairs = pooled_errors(sc, sc.cameras)
    assert pairs >= 4
    assert rel.median() < 0.002 and (rel < 0.01).float().mean() > 0.9
    short_side = []
    for cam in sc.cameras:
        K = cam.K.clone()
        K[0, 0] = K[1, 1] = cam.fx * min(WIDE) / max(WIDE)
        short_side.append(Camera(K, cam.world_to_cam, cam.width, cam.height))
    bad = pooled_errors(sc, short_side)[0]
    assert bad.median() > 5 * rel.median() and bad.median() > 0.002


def test_a_finished_16_9_scene_is_skipped(wide):
    cmd = wide[1]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "1 of 1 scenes already rendered" in res.stdout


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--size", "64", "--width", "96", "--height", "54"), "without --size"),
        (("--width", "96"), "--width and --height go together"),
        (("--width", "96", "--height", "6"), ">= 8 px"),
    ],
)
def test_the_renderer_refuses_bad_image_sizes(tmp_path, capsys, extra, message):
    from scenes.render import main

    with pytest.raises(SystemExit) as stop:
        main(["--name", "tabletop", "--seed", "7", "--out", str(tmp_path / "never"), *extra])
    assert stop.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "never").exists()


def test_the_cli_offers_the_renderers_denoiser_settings():
    """``prosplat scenes render --denoise-quality`` and the demo's ``--denoise`` list
    :data:`prosplat.data.render_jobs.DENOISE_QUALITIES`, a bpy-free copy of the renderer's
    own table: the two must name the same settings."""
    from prosplat.data.render_jobs import DENOISE_QUALITIES
    from scenes.render import DENOISE_QUALITY

    assert set(DENOISE_QUALITIES) == set(DENOISE_QUALITY)
