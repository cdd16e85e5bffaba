"""The worker line protocol of ``prosplat scenes render`` (bpy-free)."""

from __future__ import annotations

import io

from scenes.jobs import answer_line, read_answer


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
