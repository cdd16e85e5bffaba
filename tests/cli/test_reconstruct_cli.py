"""``prosplat reconstruct`` and ``prosplat eval posed`` end to end, on posed sets the tests make."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch
from posed_data import scene_cameras, write_colmap_project, write_transforms_set
from synthetic_scenes import textured_plane_views

from prosplat import ProSplat, read_ply
from prosplat.cli import build_parser
from prosplat.cli.reconstruct import refine_kwargs
from prosplat.convert.distortion import Distortion
from prosplat.convert.nerfstudio import Frame, read_transforms, write_transforms
from prosplat.core.image_io import read_image, write_image
from prosplat.eval.posed import ROWS, PosedCase, input_sets, score_cases
from prosplat.metrics import psnr
from prosplat.pipeline.posed_views import load_posed_set, pick_views

LENS = Distortion("opencv", k1=-0.2, k2=0.05, p1=0.002, p2=-0.001)


def cli(*argv) -> int:
    args = build_parser().parse_args([str(a) for a in argv])
    return args.func(args)


@pytest.fixture(scope="module")
def colmap_text(tmp_path_factory) -> Path:
    return write_colmap_project(tmp_path_factory.mktemp("colmap") / "proj", scene_cameras(5))


def _one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    err = [e for e in err if e.strip() and not e.startswith(("reading", "rendering"))]  # tqdm
    assert len(err) == 1 and err[0].startswith(f"prosplat {command}: "), err
    return err[0]


def test_reconstruct_colmap_text_writes_ply_renders_and_report(colmap_text, tmp_path, capsys):
    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--max-renders", "2") == 0  # fmt: skip
    g = read_ply(out / "gaussians.ply")
    assert len(g) > 100 and torch.isfinite(g.means).all()
    renders = sorted(p.name for p in (out / "renders").iterdir())
    # inputs 000 and 004 (the ends of the arc); 2 of the 3 held-out frames, raw + enhanced
    assert renders == ["001_enhanced.png", "001_raw.png", "002_enhanced.png", "002_raw.png"]
    raw = read_image(out / "renders" / "001_raw.png")
    assert raw.shape == (3, 32, 32) and raw.std() > 0.02  # a picture, not a blank
    report = (out / "report.md").read_text()
    assert "colmap text" in report and "input views: 000, 004" in report
    assert "COLMAP points seen by the inputs" in report
    tf = read_transforms(out / "transforms.json")  # the inputs as used, openable in Blender
    assert [f.file_path for f in tf.frames] == ["inputs/000.png", "inputs/004.png"]
    assert tf.meta["near"] > 0 and tf.meta["far"] > tf.meta["near"]
    before = (out / "gaussians.ply").read_bytes()

    capsys.readouterr()
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32") == 2  # never clobbers
    assert "not empty" in _one_line_error(capsys, "reconstruct")
    assert (out / "gaussians.ply").read_bytes() == before
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--num-inputs", "3",
               "--render", "none", "--overwrite") == 0  # fmt: skip
    assert (out / "gaussians.ply").read_bytes() != before


def test_reconstruct_colmap_binary_with_distortion(tmp_path):
    proj = write_colmap_project(tmp_path / "proj", scene_cameras(5), LENS, binary=True)
    assert not (proj / "sparse" / "0" / "cameras.txt").exists()
    out = tmp_path / "out"
    assert cli("reconstruct", proj, "--out", out, "--size", "32", "--inputs", "000", "3",
               "--render", "002") == 0  # fmt: skip
    report = (out / "report.md").read_text()
    assert "colmap binary" in report and "opencv distortion, undistorted" in report
    assert "input views: 000, 003" in report and "COLMAP points" in report
    assert sorted(p.name for p in (out / "renders").iterdir()) == [
        "002_enhanced.png",
        "002_raw.png",
    ]
    tf = read_transforms(out / "transforms.json")
    assert tf.frames[0].camera.width == 32  # undistorted, then resized


def test_reconstruct_distorted_instant_ngp_transforms(tmp_path):
    path = write_transforms_set(tmp_path / "fox", scene_cameras(4), LENS)
    out = tmp_path / "out"
    assert cli("reconstruct", path, "--out", out, "--size", "32", "--render", "all",
               "--no-triangulate") == 0  # fmt: skip
    names = sorted(p.name for p in (out / "renders").iterdir())
    assert names == sorted(f"{i:03d}_{k}.png" for i in range(4) for k in ("raw", "enhanced"))
    report = (out / "report.md").read_text()
    assert "opencv distortion, undistorted" in report and "the input cameras" in report


def test_reconstruct_triangulates_a_set_without_near_far_or_points(tmp_path, capsys):
    """A transforms.json set with neither near/far nor points (the textured plane at z = 3):
    the report names the points triangulated from the inputs (--no-triangulate: the cameras),
    and with --anchors the views whose depth was scaled to them."""
    images, cams = textured_plane_views()
    (tmp_path / "set" / "images").mkdir(parents=True)
    frames = []
    for i, (img, cam) in enumerate(zip(images, cams, strict=True)):
        write_image(tmp_path / "set" / "images" / f"{i}.png", img)
        frames.append(Frame(cam, f"images/{i}.png", {}))
    write_transforms(tmp_path / "set" / "transforms.json", frames, {})
    runs = ((["--no-triangulate"], "the input cameras"),
            ([], "points triangulated from the 3 inputs"),
            (["--anchors"], "depth scaled to the points in 3 of 3 views (x"))  # fmt: skip
    for k, (flag, source) in enumerate(runs):
        out = tmp_path / f"out{k}"
        assert cli("reconstruct", tmp_path / "set", "--out", out, "--size", "64",
                   "--render", "none", *flag) == 0  # fmt: skip
        report = (out / "report.md").read_text()
        assert source in report and ("depth scaled" in report) == (flag == ["--anchors"])
    capsys.readouterr()
    assert cli("reconstruct", tmp_path / "set", "--out", tmp_path / "out3", "--size", "64",
               "--render", "none", "--anchors", "--no-triangulate") == 0  # fmt: skip
    assert "--anchors: no points anchor these inputs (near/far from the input cameras)" in (
        capsys.readouterr().out
    )


def _break(path: Path, how: str) -> None:
    data = json.loads(path.read_text())
    if how == "nan pose":
        data["frames"][1]["transform_matrix"][0][3] = float("nan")
    elif how == "no frames":
        data["frames"] = []
    path.write_text(json.dumps(data))


@pytest.mark.parametrize(
    ("how", "match"),
    [
        ("missing image", "001.png"),
        ("nan pose", "NaN"),
        ("no frames", "no frames"),
        ("no such input", "does not exist"),
        ("bad background", "white, black or R,G,B"),
        ("bad size", "multiple of 32"),
        ("bad other-views opacity", "--other-views-opacity"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, how, match):
    path = write_transforms_set(tmp_path / "set", scene_cameras(3, 32, 32))
    extra = []
    if how == "missing image":
        (tmp_path / "set" / "images" / "001.png").unlink()
    elif how in ("nan pose", "no frames"):
        _break(path, how)
    elif how == "no such input":
        path = tmp_path / "nowhere" / "transforms.json"
    elif how == "bad background":
        extra = ["--background", "pink"]
    elif how == "bad size":
        extra = ["--size", "40"]
    elif how == "bad other-views opacity":
        extra = ["--other-views-opacity", "1.5"]
    capsys.readouterr()
    assert cli("reconstruct", path, "--out", tmp_path / "out", "--size", "32", *extra) == 2
    assert match in _one_line_error(capsys, "reconstruct")
    assert not (tmp_path / "out").exists()  # nothing written on bad input


def test_missing_images_are_skipped_only_when_asked(tmp_path, colmap_text, capsys):
    """instant-ngp's fox lists 67 frames for its 50 images: --skip-missing leaves such frames
    out and names them; without it the one-line error says how many and points to the flag."""
    path = write_transforms_set(tmp_path / "set", scene_cameras(5, 32, 32))
    for name in ("001.png", "003.png"):
        (tmp_path / "set" / "images" / name).unlink()
    capsys.readouterr()
    assert cli("reconstruct", path, "--out", tmp_path / "a", "--size", "32") == 2
    err = _one_line_error(capsys, "reconstruct")
    assert "2 of 5 frames have no image" in err and "--skip-missing" in err
    out = tmp_path / "b"
    assert cli("reconstruct", path, "--out", out, "--size", "32", "--skip-missing",
               "--num-inputs", "2", "--render", "all") == 0  # fmt: skip
    assert "left out 2 frames" in capsys.readouterr().out
    report = (out / "report.md").read_text()
    assert "left out 2 frames" in report and "(001, 003)" in report
    renders = sorted(p.name for p in (out / "renders").iterdir())
    kept = ("000", "002", "004")
    assert renders == sorted(f"{i}_{k}.png" for i in kept for k in ("raw", "enhanced"))
    with pytest.raises(ValueError, match="no frame named '003'"):  # a left-out frame is gone
        pick_views(load_posed_set(path, skip_missing=True), ["003", "000"])

    proj = write_colmap_project(tmp_path / "proj", scene_cameras(4, 32, 32))
    (proj / "images" / "002.png").unlink()
    with pytest.raises(FileNotFoundError, match="002.png .*--skip-missing"):
        load_posed_set(proj)
    posed = load_posed_set(proj, skip_missing=True)
    assert posed.names == ["000", "001", "003"] and posed.missing == ["002"]
    assert set(posed.observed) == {"000", "001", "003"}
    for name in ("000", "001", "003"):
        (proj / "images" / f"{name}.png").unlink()
    with pytest.raises(FileNotFoundError, match="4 of 4 frames"):  # nothing left: still an error
        load_posed_set(proj, skip_missing=True)


def test_refine_flags_are_passed_only_when_given():
    """Only the flags given become keywords, named as ProSplat.reconstruct names them; a step
    count of 0 is "off", so it may stand beside a time budget, but two budgets may not."""
    import inspect

    from prosplat import ProSplat

    params = inspect.signature(ProSplat.reconstruct).parameters
    assert refine_kwargs(None, None) == {}
    assert refine_kwargs(10, None) == {"refine_steps": 10}
    assert refine_kwargs(None, 2.5) == {"refine_seconds": 2.5}
    assert set(refine_kwargs(0, 2.5)) <= set(params)
    with pytest.raises(ValueError, match="not both"):
        refine_kwargs(10, 2.5)


def test_refine_keeps_the_budget_and_reports_its_fit(colmap_text, tmp_path, capsys):
    """--budget prunes before refinement as without it (it was dropped when refining before
    2026-11-28), a progress bar shows the steps and the report says what the fit did."""
    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--render", "none", "--refine-steps", "3", "--budget", "300") == 0  # fmt: skip
    assert len(read_ply(out / "gaussians.ply")) == 300
    assert "refining against the inputs" in capsys.readouterr().err
    report = (out / "report.md").read_text()
    assert "budget kept 300 of 2,048; refined 3 steps in" in report
    assert "input-view loss" in report


def test_merge_flat_merges_what_was_placed_above_the_matching_size(colmap_text, tmp_path):
    """--merge-flat: at 256 px the Gaussians are placed at twice the shipped generator's
    128-px matching size, so flat 2x2 blocks merge; the report says how many, and the PLY
    holds what the budget kept after the merge."""
    import re

    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "256", "--num-inputs", "2",
               "--render", "none", "--merge-flat") == 0  # fmt: skip
    report = (out / "report.md").read_text()
    found = re.search(r"budget kept ([\d,]+) of ([\d,]+) \(([\d,]+) merged away", report)
    assert found, report
    kept, total, merged = (int(x.replace(",", "")) for x in found.groups())
    assert merged > 0 and kept < total
    assert len(read_ply(out / "gaussians.ply")) == kept


def test_cross_view_fade_zero_drops_what_another_input_saw_through(colmap_text, tmp_path, capsys):
    """--cross-view-fade 0: the Gaussians another input saw through are dropped after the
    budget; the report says how many and the PLY holds the rest. A value outside [0, 1] is a
    one-line usage error before any work."""
    import re

    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "64", "--num-inputs", "3",
               "--render", "none", "--cross-view-fade", "0") == 0  # fmt: skip
    report = (out / "report.md").read_text()
    found = re.search(r"budget kept ([\d,]+) of ([\d,]+); ([\d,]+) faded where another", report)
    assert found, report
    kept, total, faded = (int(x.replace(",", "")) for x in found.groups())
    assert faded > 0 and kept < total
    assert len(read_ply(out / "gaussians.ply")) == kept
    capsys.readouterr()
    bad = tmp_path / "bad"
    with pytest.raises(SystemExit) as exit_:
        cli("reconstruct", colmap_text, "--out", bad, "--cross-view-fade", "1.5")
    assert exit_.value.code == 2 and "must be 0-1, got 1.5" in capsys.readouterr().err
    assert not bad.exists()


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (("--refine-steps", "-1"), "--refine-steps must be >= 0"),
        (("--refine-seconds", "0"), "--refine-seconds must be a number of seconds > 0"),
        (("--refine-steps", "5", "--refine-seconds", "2"), "not both"),
    ],
)
def test_bad_refine_flags_fail_before_any_work(colmap_text, tmp_path, capsys, flags, message):
    out = tmp_path / "out"
    code = cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--render", "none", *flags)
    assert code == 2
    assert message in _one_line_error(capsys, "reconstruct")
    assert not out.exists()  # nothing written


def test_eval_posed_scores_the_rows_and_shows_them(colmap_text, tmp_path, capsys):
    out = tmp_path / "eval"
    assert cli("eval", "posed", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--targets", "2") == 0  # fmt: skip
    plain = ROWS[:5]  # flat, paste, generator (filled), enhanced: no refinement asked for
    table = capsys.readouterr().out
    for row in ROWS:
        assert (f"| {row} |" in table) == (row in plain), row
    rows = list(csv.DictReader(open(out / "scores.csv")))
    assert len(rows) == 2 * len(plain)
    assert all(0 < float(r["psnr"]) < 100 and 0 <= float(r["lpips"]) for r in rows)
    summary = json.loads((out / "scores.json").read_text())["summary"]
    assert [s["method"] for s in summary] == list(plain)
    assert (out / "summary.md").read_text().strip() in table
    # views.png: 2 targets x (ground truth + 5 rows) of 32x32 with 2-px gaps
    assert read_image(out / "views.png").shape == (3, 2 * 34 - 2, 6 * 34 - 2)
    assert cli("eval", "posed", colmap_text, "--out", out, "--size", "32") == 2  # never clobbers

    out = tmp_path / "refined"
    assert cli("eval", "posed", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--targets", "1", "--refine-steps", "3") == 0  # fmt: skip
    summary = json.loads((out / "scores.json").read_text())["summary"]
    by = {s["method"]: s for s in summary}
    assert list(by) == list(ROWS)
    assert by["refined"]["recon_s"] > 0 and by["refined"]["gaussians"] > 0
    assert read_image(out / "views.png").shape == (3, 32, 9 * 34 - 2)


def test_eval_posed_input_sets_scores_each_choice_and_their_mean(tmp_path, capsys):
    """--input-sets 3: three different choices of 2 inputs among 6 frames, the first the
    default one; every choice's held-out frames are scored (its own inputs never are), the
    summary's means are over all of them, and summary.md has one column per choice."""
    cams = scene_cameras(6, 32, 32)
    posed_file = write_transforms_set(tmp_path / "set", cams)
    posed = load_posed_set(posed_file)
    sets = input_sets(posed, pick_views(posed, None, 2), 3)
    assert len(sets) == 3 and len({tuple(s) for s in sets}) == 3
    assert sets[0] == sorted(pick_views(posed, None, 2))
    out = tmp_path / "eval"
    assert cli("eval", "posed", posed_file, "--out", out, "--size", "32", "--num-inputs", "2",
               "--targets", "2", "--input-sets", "3") == 0  # fmt: skip
    printed = capsys.readouterr().out
    rows = list(csv.DictReader(open(out / "scores.csv")))
    cases = sorted({r["scene"] for r in rows})
    assert cases == ["set set 0", "set set 1", "set set 2"]
    paste = [float(r["psnr"]) for r in rows if r["method"] == "paste"]
    assert len(paste) == 3 * 2  # 2 targets per choice
    summary = json.loads((out / "scores.json").read_text())["summary"]
    by = {s["method"]: s for s in summary}
    assert by["paste"]["psnr"] == pytest.approx(sum(paste) / len(paste), rel=1e-6)
    md = (out / "summary.md").read_text()
    assert "| method | set set 0 | set set 1 | set set 2 |" in md
    assert "set set 2: inputs" in printed
    with pytest.raises(ValueError, match="drop --inputs"):
        input_sets(posed, [0, 1], 2, fixed=True)
    with pytest.raises(ValueError, match=">= 1"):
        input_sets(posed, [0, 1], 0)
    assert input_sets(posed, [1, 0], 1) == [[1, 0]]  # the inputs as given, in their order
    # farthest-point sampling from frame 3 (the second choice's start) picks frames 0 and 3:
    # given as [3, 0] they are the same choice in another order, so it is skipped
    assert input_sets(posed, [3, 0], 2) == [[3, 0], [1, 5]]


def test_score_cases_flat_and_paste_rows():
    """A target that *is* input 0 makes paste exact (PSNR at its 100 dB cap) and flat the
    inputs' mean colour; the generator row is scored on the same target."""
    torch.manual_seed(0)
    model = ProSplat()  # untrained, no improvement model: no enhanced row
    cams = scene_cameras(2, 32, 32)
    images = torch.rand(2, 3, 32, 32)
    case = PosedCase(images, cams, images[:1], cams[:1], 1.0, 10.0, "unit")
    rows = score_cases(model, [case])
    by = {r.method: r for r in rows}
    assert list(by) == ["flat", "paste", "generator", "generator filled"]
    assert by["paste"].psnr == pytest.approx(100.0)
    # the same Gaussians, shown with their holes filled (random images: no better or worse)
    assert by["generator filled"].gaussians == by["generator"].gaussians
    assert 0 < by["generator filled"].psnr < 100
    flat = images.mean(dim=(0, 2, 3))[:, None, None].expand(3, 32, 32)
    assert by["flat"].psnr == pytest.approx(float(psnr(flat, images[0])), abs=1e-4)
    assert by["generator"].psnr < 100 and by["generator"].gaussians > 0


def test_score_cases_refines_the_budgeted_gaussians():
    """``budget`` prunes the refined rows' Gaussians as it prunes the generator's (it was
    dropped for refinement before 2026-11-26, so ``--budget`` changed only some rows)."""
    torch.manual_seed(0)
    model = ProSplat()
    cams = scene_cameras(2, 32, 32)
    images = torch.rand(2, 3, 32, 32)
    case = PosedCase(images, cams, images[:1], cams[:1], 1.0, 10.0, "unit")
    rows = score_cases(model, [case], budget=500, reconstruct_kwargs={"refine_steps": 2})
    by = {r.method: r for r in rows}
    assert by["generator"].gaussians == by["refined"].gaussians <= 500


def test_render_a_camera_path(colmap_text, tmp_path):
    """--render PATH.json renders the cameras of another transforms file (e.g. exported from
    Blender), at the model resolution."""
    from prosplat.convert.nerfstudio import Frame, write_transforms

    cams = scene_cameras(3, 128, 96)  # another size than the photos, same aspect
    path = write_transforms(
        tmp_path / "path.json", [Frame(c, f"cam{i}") for i, c in enumerate(cams)]
    )
    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--render", path) == 0  # fmt: skip
    names = sorted(p.name for p in (out / "renders").iterdir())
    assert names == sorted(
        f"path_{i:03d}_cam{i}_{k}.png" for i in range(3) for k in ("raw", "enhanced")
    )
    assert read_image(out / "renders" / "path_000_cam0_raw.png").shape == (3, 32, 32)
    assert "camera path" in (out / "report.md").read_text()


def test_distill_steps_fit_the_enhanced_renders(colmap_text, tmp_path, capsys):
    """--distill-steps renders every camera again from the Gaussians fitted to the inputs and
    the enhanced renders: closer to the enhanced views than the raw renders were, written
    beside them with their own PLY; nothing to fit is a one-line error."""
    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--render", "all", "--distill-steps", "150") == 0  # fmt: skip
    # the same Gaussians, refined, and one more for each hole pixel of the fitted views
    # (prosplat.geometry.hole_gaussians)
    assert len(read_ply(out / "gaussians_distilled.ply")) >= len(read_ply(out / "gaussians.ply"))
    gaps = []
    for name in ("001", "002", "003"):
        raw, enh, dis = (read_image(out / "renders" / f"{name}_{k}.png")
                         for k in ("raw", "enhanced", "distilled"))  # fmt: skip
        gaps.append((float((raw - enh).abs().mean()), float((dis - enh).abs().mean())))
    assert sum(d for _, d in gaps) < 0.7 * sum(r for r, _ in gaps), gaps
    report = (out / "report.md").read_text()
    assert "distilled 150 steps from 5 enhanced views" in report
    assert "![](renders/001_distilled.png)" in report
    capsys.readouterr()
    assert cli("reconstruct", colmap_text, "--out", tmp_path / "none", "--size", "32",
               "--render", "none", "--distill-steps", "10") == 2  # fmt: skip
    assert "needs an improvement model and cameras" in _one_line_error(capsys, "reconstruct")


def test_reconstruct_nerf_synthetic_rgba_says_white(tmp_path):
    alpha = torch.ones(32, 32)
    alpha[:, :8] = 0
    path = write_transforms_set(tmp_path / "lego", scene_cameras(3, 32, 32), rgba_alpha=alpha,
                                angle_x=True)  # fmt: skip
    out = tmp_path / "out"
    assert cli("reconstruct", path, "--out", out, "--size", "32", "--num-inputs", "2") == 0
    assert "background for RGBA: white (NeRF-synthetic" in (out / "report.md").read_text()
    assert read_image(out / "inputs" / "000.png")[:, :, :8].min() == 1.0  # composited on white


def test_eval_posed_with_a_separate_target_set(tmp_path, capsys):
    """NeRF synthetic's protocol: inputs from transforms_train.json, targets from
    transforms_test.json (same world frame)."""
    cams = scene_cameras(5, 32, 32)
    train = write_transforms_set(tmp_path / "train", cams[0::2])  # 3 frames, all inputs
    test = write_transforms_set(tmp_path / "test", cams[1::2])  # 2 other frames
    out = tmp_path / "eval"
    assert cli("eval", "posed", train, "--out", out, "--size", "32", "--num-inputs", "3",
               "--target-set", test) == 0  # fmt: skip
    rows = list(csv.DictReader(open(out / "scores.csv")))
    assert len(rows) == 2 * 5 and {r["views"] for r in rows} == {"3"}  # 5 rows, filled too
    capsys.readouterr()
    assert cli("eval", "posed", train, "--out", tmp_path / "e2", "--size", "32",
               "--num-inputs", "3") == 2  # no held-out frame left, and no target set  # fmt: skip
    assert "--target-set" in _one_line_error(capsys, "eval posed")
    # a target set's frames without images are left out and named too (--skip-missing)
    (tmp_path / "test" / "images" / "001.png").unlink()
    assert cli("eval", "posed", train, "--out", tmp_path / "e3", "--size", "32", "--num-inputs",
               "3", "--target-set", test, "--skip-missing") == 0  # fmt: skip
    assert "left out 1 frames" in capsys.readouterr().out
    assert len(list(csv.DictReader(open(tmp_path / "e3" / "scores.csv")))) == 1 * 5


def test_fill_holes_writes_filled_renders_beside_the_raw_ones(colmap_text, tmp_path, capsys):
    """--fill-holes: NAME_filled.png is NAME_raw.png completed over the pull-push fill (same
    where the render is opaque, never darker), the raw render is kept as it was; a set
    composited over white refuses the flag."""
    out = tmp_path / "out"
    assert cli("reconstruct", colmap_text, "--out", out, "--size", "32", "--num-inputs", "2",
               "--max-renders", "2", "--fill-holes") == 0  # fmt: skip
    names = sorted(p.name for p in (out / "renders").iterdir())
    assert names == [f"00{i}_{k}.png" for i in (1, 2) for k in ("enhanced", "filled", "raw")]
    raw = read_image(out / "renders" / "001_raw.png")
    filled = read_image(out / "renders" / "001_filled.png")
    assert raw.shape == filled.shape == (3, 32, 32)
    assert (filled >= raw - 2 / 255).all()  # over black: the fill only adds light
    plain = tmp_path / "plain"
    assert cli("reconstruct", colmap_text, "--out", plain, "--size", "32", "--num-inputs", "2",
               "--max-renders", "2") == 0  # fmt: skip
    assert torch.equal(read_image(plain / "renders" / "001_raw.png"), raw)
    capsys.readouterr()
    assert cli("reconstruct", colmap_text, "--out", tmp_path / "white", "--size", "32",
               "--background", "white", "--fill-holes") == 2  # fmt: skip
    assert "--fill-holes" in _one_line_error(capsys, "reconstruct")
