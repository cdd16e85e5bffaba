"""The worker line protocol of ``prosplat scenes render`` (bpy-free, in
:mod:`prosplat.data.render_jobs`) and the command line of its workers."""

from __future__ import annotations

import io

import pytest

from prosplat.cli import build_parser
from prosplat.cli.scenes import cmd_scenes_render, render_worker_command
from prosplat.data.render_jobs import answer_line, image_size, read_answer


def test_an_answer_is_found_after_blender_text_on_its_line():
    done = answer_line(True, {"name": "room", "seed": 3, "folder": "out/room_000003"})
    stream = io.StringIO("Fra:1 Mem:3M | Rendering\nSaved: x.png" + done + "\nnext\n")
    answer, tail = read_answer(stream)
    assert answer == {"name": "room", "seed": 3, "folder": "out/room_000003"}
    assert tail == ["Fra:1 Mem:3M | Rendering"]
    assert stream.readline() == "next\n"  # the next job's output is left unread


def test_a_failure_carries_its_error_and_a_dead_worker_returns_none():
    failed = answer_line(False, {"name": "nope", "seed": 0, "error": ["ValueError: nope"]})
    answer, _ = read_answer(io.StringIO(failed + "\n"))
    assert answer["error"] == ["ValueError: nope"] and "folder" not in answer
    lines = "".join(f"line {i}\n" for i in range(20))
    answer, tail = read_answer(io.StringIO(lines), keep=5)
    assert answer is None and tail == [f"line {i}" for i in range(15, 20)]


def test_the_worker_command_shares_the_cores_unless_threads_is_given(monkeypatch, tmp_path):
    import os

    def threads_of(*extra: str) -> int:
        args = build_parser().parse_args(["scenes", "render", "--out", str(tmp_path), *extra])
        cmd = render_worker_command(args)
        return int(cmd[cmd.index("--threads") + 1])

    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert threads_of() == 4  # 2 workers by default
    assert threads_of("--workers", "3") == 2
    assert threads_of("--workers", "16") == 1
    assert threads_of("--workers", "2", "--threads", "1") == 1
    bad = build_parser().parse_args(["scenes", "render", "--out", str(tmp_path), "--threads", "0"])
    assert cmd_scenes_render(bad) == 2  # refused before any Blender starts


def test_the_worker_command_carries_the_denoiser_setting(tmp_path):
    """--denoise-quality reaches the worker's command line with --denoise; without --denoise a
    setting other than the default is refused before any Blender starts."""

    def command(*extra: str) -> list[str]:
        args = build_parser().parse_args(["scenes", "render", "--out", str(tmp_path), *extra])
        return render_worker_command(args)

    cmd = command("--denoise", "--denoise-quality", "fast")
    assert cmd[cmd.index("--denoise-quality") + 1] == "fast" and "--denoise" in cmd
    cmd = command("--denoise")
    assert cmd[cmd.index("--denoise-quality") + 1] == "high"
    assert "--denoise" not in command() and "--denoise-quality" not in command()
    out = tmp_path / "never"
    bad = build_parser().parse_args(
        ["scenes", "render", "--out", str(out), "--denoise-quality", "fast"]
    )
    assert cmd_scenes_render(bad) == 2 and not out.exists()


def test_image_size_is_square_by_default_or_width_by_height():
    assert image_size(None, None, None) == (128, 128)
    assert image_size(64, None, None) == (64, 64)
    assert image_size(None, 96, 54) == (96, 54)
    assert image_size(None, 36, 64) == (36, 64)  # portrait too
    assert image_size(None, 8, 8) == (8, 8)


@pytest.mark.parametrize(
    ("size", "width", "height", "fix"),
    [
        (64, 96, 54, "without --size"),  # both kinds together
        (64, 96, None, "without --size"),
        (None, 96, None, "pass both"),  # only one side
        (None, None, 54, "pass both"),
        (None, 96, 7, ">= 8"),
        (4, None, None, ">= 8"),
    ],
)
def test_image_size_refuses_with_a_one_line_fix(size, width, height, fix):
    with pytest.raises(ValueError, match=fix) as err:
        image_size(size, width, height)
    assert "\n" not in str(err.value)


def _render_args(tmp_path, *extra: str):
    return build_parser().parse_args(["scenes", "render", "--out", str(tmp_path), *extra])


def _size_of(cmd: list[str]) -> tuple[int, int]:
    assert "--size" not in cmd  # the worker always gets both sides
    return int(cmd[cmd.index("--width") + 1]), int(cmd[cmd.index("--height") + 1])


def test_the_worker_command_carries_width_and_height(tmp_path):
    assert _size_of(render_worker_command(_render_args(tmp_path))) == (128, 128)
    assert _size_of(render_worker_command(_render_args(tmp_path, "--size", "64"))) == (64, 64)
    wide = _render_args(tmp_path, "--width", "96", "--height", "54")
    assert _size_of(render_worker_command(wide)) == (96, 54)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            ("--size", "64", "--width", "96", "--height", "54"),
            "--width W --height H without --size",
        ),
        (("--width", "96"), "--width and --height go together"),
        (("--height", "54"), "--width and --height go together"),
        (("--width", "96", "--height", "4"), ">= 8 px"),
        (("--size", "4"), ">= 8 px"),
    ],
)
def test_bad_image_sizes_are_refused_before_any_blender_starts(tmp_path, capsys, extra, message):
    out = tmp_path / "never"
    assert cmd_scenes_render(_render_args(out, *extra)) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("prosplat scenes render:")
    assert not out.exists()
