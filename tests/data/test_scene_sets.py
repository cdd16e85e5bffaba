"""Named scene sets: seed ranges, the render commands that make them, and subsets as links."""

from __future__ import annotations

import json
import os

import pytest

from prosplat.cli import main
from prosplat.data.scene_sets import (
    SCENE_SETS,
    hard_round_seeds,
    link_subset,
    parse_seeds,
    scene_name,
)


def test_seed_ranges_and_hard_rounds():
    assert parse_seeds("5-7 3") == (3, 5, 6, 7)
    # two seeds per kind and round, six kinds: rounds 0-4 are the 60 of data/gen_v6
    assert len(parse_seeds("10000-10359 hard:0-4")) == 420
    assert hard_round_seeds(2, 3)[:4] == [20004, 20005, 20006, 20007]
    assert scene_name(20105) == "specular" and scene_name(950105) == "inside_outside"
    assert scene_name(10003) is None
    for bad in ("9-3", "a-b", "hard:x"):
        with pytest.raises(ValueError):
            parse_seeds(bad)


def test_render_commands_group_seeds_by_scene_kind():
    lines = SCENE_SETS["train128"].render_commands("10000-10009 hard:1", "d")
    assert lines[0] == (
        "prosplat scenes render --seed 10000 --count 10 --size 128 --inputs 6 --targets 10 "
        "--samples 8 --denoise --denoise-quality fast --out d/train128"
    )
    assert lines[1].startswith("prosplat scenes render --seed 20002 --count 2 --scene textureless")
    assert len(lines) == 7
    test = SCENE_SETS["test128"].render_commands()
    assert len(test) == 7 and "--seed 987000 --count 18" in test[-1]


def _scene(root, name):
    (root / name).mkdir(parents=True)
    (root / name / "transforms.json").write_text(json.dumps({"frames": []}))


def test_a_subset_links_exactly_its_seeds_and_is_kept_when_unchanged(tmp_path):
    root = tmp_path / "train128"
    for name in ("room_010000", "open_010001", "tabletop_010002", "specular_020100"):
        _scene(root, name)
    dest = link_subset(root, parse_seeds("10000-10001 20100"), tmp_path / "runs" / "sub")
    names = sorted(p.name for p in dest.iterdir())
    assert names == ["open_010001", "room_010000", "specular_020100"]
    assert all(not os.path.isabs(os.readlink(p)) and p.resolve().is_dir() for p in dest.iterdir())
    before = dest.stat().st_mtime_ns
    assert link_subset(root, parse_seeds("10000-10001 20100"), dest) == dest
    assert dest.stat().st_mtime_ns == before  # the same links: left alone
    link_subset(root, parse_seeds("10002"), dest)  # other links: replaced
    assert [p.name for p in dest.iterdir()] == ["tabletop_010002"]
    with pytest.raises(FileNotFoundError, match="1 of 2 scenes are not rendered"):
        link_subset(root, [10000, 10005], tmp_path / "other")
    _scene(tmp_path, "mine")  # a folder of the user's, not links: never replaced
    with pytest.raises(FileExistsError):
        link_subset(root, [10000], tmp_path / "mine")


def test_the_scenes_cli_prints_sets_and_makes_subsets(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["scenes", "sets", "val128", "--root", "data"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == (
        "prosplat scenes render --seed 900000 --count 8 --size 128 --inputs 6 --targets 10 "
        "--samples 16 --denoise --out data/val128"
    )
    _scene(tmp_path / "t", "room_010000")
    with pytest.raises(SystemExit) as done:
        main(["scenes", "subset", "--data", str(tmp_path / "t"), "--seeds", "10000",
              "--out", str(tmp_path / "s")])  # fmt: skip
    assert done.value.code == 0 and (tmp_path / "s" / "room_010000").is_symlink()
    with pytest.raises(SystemExit) as done:
        main(["scenes", "subset", "--data", str(tmp_path / "t"), "--seeds", "10001",
              "--out", str(tmp_path / "s")])  # fmt: skip
    assert done.value.code == 2 and "not rendered" in capsys.readouterr().err
