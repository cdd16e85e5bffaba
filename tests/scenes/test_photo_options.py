"""Photo-like cameras for the rendered scenes, without Blender: the roll and lens draws
(:mod:`prosplat.data.rigs`), the ``--roll`` / ``--lens-range`` options of ``prosplat scenes
render`` and its workers, and the ``photo128`` set's commands."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch

from prosplat import Camera
from prosplat.cli import build_parser
from prosplat.cli.scenes import cmd_scenes_render, render_worker_command
from prosplat.data.rigs import draw_lens, draw_roll, parse_lens_range, parse_roll, roll_camera
from prosplat.data.scene_sets import SCENE_SETS
from prosplat.data.splits import split_of


def _level() -> Camera:
    return Camera.look_at((2.0, -1.0, 1.5), (0.0, 0.2, 0.4), (0.0, 0.0, 1.0), 40.0, 32, 24)


def test_a_rolled_camera_keeps_centre_axis_and_intrinsics_and_turns_up_by_the_angle():
    cam = _level()
    for degrees in (-35.0, 7.5, 20.0, 90.0):
        rolled = roll_camera(cam, degrees)
        assert torch.allclose(rolled.center, cam.center, atol=1e-12)
        assert torch.allclose(rolled.forward, cam.forward, atol=1e-12)
        assert torch.equal(rolled.K, cam.K) and (rolled.width, rolled.height) == (32, 24)
        up, up_rolled, right = -cam.R[1], -rolled.R[1], cam.R[0]
        angle = math.degrees(math.atan2(float(-up_rolled @ right), float(up_rolled @ up)))
        assert angle == pytest.approx(degrees, abs=1e-9)  # up turns towards the old left
    # the camera's principal point stays the image centre: a point on the axis projects there
    uv, _ = roll_camera(cam, 20.0).project(cam.center + 3 * cam.forward)
    assert torch.allclose(uv, torch.tensor([16.0, 12.0], dtype=uv.dtype), atol=1e-9)


def test_no_roll_is_the_very_same_camera():
    cam = _level()
    assert roll_camera(cam, 0.0) is cam
    assert draw_roll(5, 3, 0.0) == 0.0


def test_the_roll_draw_is_seeded_per_scene_and_view_and_stays_in_range():
    draws = [draw_roll(seed, view, 20.0) for seed in range(40) for view in range(16)]
    assert all(-20.0 <= d <= 20.0 for d in draws)
    assert min(draws) < -15 and max(draws) > 15  # spread over the range
    assert draw_roll(7, 2, 20.0) == draw_roll(7, 2, 20.0)
    assert len({draw_roll(7, v, 20.0) for v in range(16)}) == 16
    assert draw_roll(7, 2, 20.0) != draw_roll(8, 2, 20.0)
    with pytest.raises(ValueError):
        draw_roll(7, 2, -1.0)


def test_the_lens_draw_lands_in_the_range_log_uniformly_one_per_seed():
    lenses = torch.tensor([draw_lens(seed, (24.0, 85.0)) for seed in range(2000)])
    assert float(lenses.min()) >= 24.0 and float(lenses.max()) <= 85.0
    # log-uniform: the median sits at the geometric mean, not the midpoint (54.5 mm)
    assert float(lenses.median()) == pytest.approx(math.sqrt(24 * 85), rel=0.05)
    assert draw_lens(3, (24.0, 85.0)) == draw_lens(3, (24.0, 85.0))
    assert draw_lens(3, (50.0, 50.0)) == pytest.approx(50.0)


def test_lens_ranges_and_rolls_parse_or_say_what_is_wrong():
    assert parse_lens_range("24-85") == (24.0, 85.0)
    assert parse_lens_range(" 35.5-35.5 ") == (35.5, 35.5)
    assert parse_roll("20") == 20.0 and parse_roll("0") == 0.0
    for text, message in [
        ("85-24", "runs backwards"),
        ("0-50", "must be > 0"),
        ("-24-85", "must be > 0"),
        ("24", "is not A-B"),
        ("24-", "is not A-B"),
        ("wide-tele", "is not A-B"),
    ]:
        with pytest.raises(ValueError, match=message):
            parse_lens_range(text)
    for text in ("-5", "200", "lots", "nan"):
        with pytest.raises(ValueError, match="0-180"):
            parse_roll(text)


def _args(tmp_path, *extra: str):
    return build_parser().parse_args(["scenes", "render", "--out", str(tmp_path), *extra])


def test_the_worker_command_carries_roll_and_lens_range_only_when_given(tmp_path):
    plain = render_worker_command(_args(tmp_path))
    assert "--roll" not in plain and "--lens-range" not in plain
    assert render_worker_command(_args(tmp_path, "--roll", "0")) == plain
    cmd = render_worker_command(_args(tmp_path, "--roll", "20", "--lens-range", "24-85"))
    assert cmd[cmd.index("--roll") + 1] == "20.0"
    assert parse_lens_range(cmd[cmd.index("--lens-range") + 1]) == (24.0, 85.0)
    assert cmd[: len(plain)] == plain  # the rest of the command is as before


@pytest.mark.parametrize(
    ("value", "message"),
    [("85-24", "runs backwards"), ("0-50", "must be > 0"), ("24", "is not A-B")],
)
def test_the_cli_refuses_a_bad_lens_range(tmp_path, capsys, value, message):
    with pytest.raises(SystemExit) as stop:
        _args(tmp_path / "never", "--lens-range", value)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "--lens-range" in err and message in err
    assert not (tmp_path / "never").exists()


def test_the_cli_refuses_a_bad_lens_range_before_any_blender_starts(tmp_path):
    out = tmp_path / "never"
    cmd = [sys.executable, "-m", "prosplat", "scenes", "render", "--out", str(out)]
    res = subprocess.run(cmd + ["--lens-range", "85-24"], capture_output=True, text=True)
    assert res.returncode == 2 and "runs backwards" in res.stderr
    res = subprocess.run(cmd + ["--roll", "-3"], capture_output=True, text=True)
    assert res.returncode == 2 and "0-180" in res.stderr
    assert not out.exists()


def test_a_good_lens_range_passes_the_clis_checks(tmp_path):
    args = _args(tmp_path, "--lens-range", "24-85", "--roll", "20", "--count", "0")
    assert args.lens_range == (24.0, 85.0) and args.roll == 20.0
    assert cmd_scenes_render(args) == 2  # refused for --count 0, not for the camera options


def test_photo128_renders_object_rings_with_rolled_cameras_and_a_range_of_lenses():
    photo = SCENE_SETS["photo128"]
    (command,) = photo.render_commands("30000-30009")
    assert command.startswith("prosplat scenes render --seed 30000 --count 10 --scene object_ring")
    train = SCENE_SETS["train128"].options
    assert f"{train} --roll 20 --lens-range 24-85" in command
    assert command.endswith("--out data/photo128")
    assert len(photo.render_commands()) == 1 and "--count 1000" in photo.render_commands()[0]
    assert {split_of(s) for s in (30000, 30999)} == {"train"}
    args = build_parser().parse_args(command.split()[1:])  # the command parses as printed
    assert args.scene == "object_ring" and args.lens_range == (24.0, 85.0) and args.roll == 20.0
