"""benchmarks/compare_ladders.py: two ladder runs paired target by target."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from benchmark_scripts import load_benchmark


def _module():
    return load_benchmark("compare_ladders")


def _ladder(path: Path, shift: float, types: dict[str, str]) -> Path:
    scores = [
        dict(
            rung=rung, size=64, views=4, scene=scene, scene_type=kind, target=t,
            psnr=15.0 + t + shift * (kind == "room"), lpips=0.2 - 0.01 * shift,
        )
        for rung in ("generator", "enhanced", "MORI paste")
        for scene, kind in types.items()
        for t in range(4)
    ]  # fmt: skip
    path.write_text(json.dumps({"scores": scores}))
    return path


def test_pairs_targets_and_splits_by_scene_type(tmp_path: Path, capsys) -> None:
    types = {"room_1": "room", "open_2": "open"}
    a = _ladder(tmp_path / "a.json", 0.0, types)
    b = _ladder(tmp_path / "b.json", 1.0, types)  # +1 dB on rooms only, LPIPS -0.01 everywhere
    _module().main([str(a), str(b)])
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| 64 | 4 | enhanced | 8 "))
    assert "+0.50 [" in row  # half the targets gain 1 dB
    assert "-0.010 [-0.010, -0.010]" in row
    assert "MORI paste" not in out  # only the rows asked for
    per_type = next(
        line for line in out.splitlines()[-3:] if line.startswith("| 64 | 4 | enhanced |")
    )
    assert per_type.split("|")[4:6] == [" +0.00 ", " +1.00 "]  # open, room


def test_runs_without_common_targets_are_refused(tmp_path: Path) -> None:
    a = _ladder(tmp_path / "a.json", 0.0, {"room_1": "room"})
    b = _ladder(tmp_path / "b.json", 0.0, {"open_2": "open"})
    with pytest.raises(SystemExit, match="no targets"):
        _module().main([str(a), str(b)])


def test_against_pairs_two_rows_of_one_run(tmp_path: Path, capsys) -> None:
    """``--against ROW``: each B row paired with A's ROW on the same targets, so one run's
    rows compare with each other (here the paste, 15+t dB, against itself and the others)."""
    path = tmp_path / "one.json"
    scores = [
        dict(rung=rung, size=64, views=4, scene="room_1", scene_type="room", target=t,
             psnr=15.0 + t + gain, lpips=0.3 - gain / 10)
        for rung, gain in (("MORI paste", 0.0), ("enhanced", 2.0), ("refine 100 enhanced", 2.5))
        for t in range(4)
    ]  # fmt: skip
    path.write_text(json.dumps({"scores": scores}))
    _module().main([str(path), str(path), "--rows", "enhanced", "refine 100 enhanced",
                    "--against", "MORI paste"])  # fmt: skip
    out = capsys.readouterr().out
    table = [line for line in out.splitlines() if "| 64 | 4 |" in line and "[" in line]
    lines = {line.split("|")[3].strip(): line for line in table}
    assert "+2.00 [+2.00, +2.00]" in lines["enhanced"]
    assert "+2.50 [+2.50, +2.50]" in lines["refine 100 enhanced"]
    assert "16.50 / 0.300" in lines["enhanced"]  # A is the paste's own score


def test_pairs_eval_posed_scores_by_case_and_order(tmp_path: Path, capsys) -> None:
    """eval posed's scores.json (methods as rows, targets in order within each case): B is
    +1 dB on case "fox set 1" only. The interval resamples whole cases, so with one case
    gaining and one not it spans both (0 to +1), where resampling targets would not."""

    def posed(path: Path, gain: float) -> Path:
        targets = [
            dict(method=m, views=4, kind="held-out", scene=case, psnr=15.0 + t + gain * (k == 1),
                 lpips=0.2)
            for m in ("paste", "refined enhanced")
            for k, case in enumerate(("fox set 0", "fox set 1"))
            for t in range(5)
        ]  # fmt: skip
        path.write_text(json.dumps({"summary": [], "targets": targets}))
        return path

    a, b = posed(tmp_path / "a.json", 0.0), posed(tmp_path / "b.json", 1.0)
    _module().main([str(a), str(b), "--rows", "refined enhanced"])
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("|  | 4 | refined enhanced"))
    assert "| 10 |" in row and "+0.50 [+0.00, +1.00]" in row
    per_case = out.splitlines()[-1]
    assert per_case.split("|")[4:6] == [" +0.00 ", " +1.00 "]
