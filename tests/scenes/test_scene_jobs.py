"""The worker line protocol of ``prosplat scenes render`` (bpy-free, in
:mod:`prosplat.data.render_jobs`) and the command line of its workers."""

from __future__ import annotations

import io

from prosplat.cli import build_parser
from prosplat.cli.scenes import cmd_scenes_render, render_worker_command
from prosplat.data.render_jobs import answer_line, read_answer


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
