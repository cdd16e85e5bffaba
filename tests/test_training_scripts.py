"""The shell helpers the training scripts source (scripts/scene_subset.sh), run in bash on a
fake ``data/train128``: the subset a run trains on must be exactly the seeds asked for, and
two runs that build the same subset side by side must not pull scenes from under each other.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")


def _bash(cwd: Path, script: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["bash", "-c", f". {SCRIPTS / 'scene_subset.sh'}\n{script}"],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=60,
    )


@pytest.fixture
def root(tmp_path: Path) -> Path:
    for name in ("open_010000", "room_010001", "tabletop_010002", "near_far_020000"):
        scene = tmp_path / "data" / "train128" / name
        scene.mkdir(parents=True)
        (scene / "transforms.json").write_text("{}")
    return tmp_path


def _links(folder: Path) -> dict[str, Path]:
    return {p.name: p.resolve() for p in folder.iterdir()}


def test_scene_subset_links_exactly_the_seeds(root: Path) -> None:
    r = _bash(root, 'scene_subset data/sub "10000-10001 20000-20000"')
    assert r.returncode == 0, r.stderr
    links = _links(root / "data" / "sub")
    assert sorted(links) == ["near_far_020000", "open_010000", "room_010001"]
    for name, target in links.items():
        assert target == (root / "data" / "train128" / name).resolve()
        assert (root / "data" / "sub" / name / "transforms.json").is_file()
    assert not list((root / "data").glob("sub.new.*")), "the staging folder is left behind"


def test_scene_subset_missing_seed_is_an_error_and_leaves_nothing(root: Path) -> None:
    r = _bash(root, 'scene_subset data/sub "10000-10005"')
    assert r.returncode != 0
    assert "no scene with seed 10003" in r.stderr
    assert not (root / "data" / "sub").exists()
    assert not list((root / "data").glob("sub.new.*"))


def test_scene_subset_keeps_an_identical_folder_and_replaces_another(root: Path) -> None:
    assert _bash(root, 'scene_subset data/sub "10000-10001"').returncode == 0
    sub = root / "data" / "sub"
    inode = sub.stat().st_ino
    # the same subset again (a second run starting beside the first): the folder is untouched
    assert _bash(root, 'scene_subset data/sub "10000-10001"').returncode == 0
    assert sub.stat().st_ino == inode
    # another subset: the folder is replaced, with no link of the old one left
    assert _bash(root, 'scene_subset data/sub "10002-10002"').returncode == 0
    assert sorted(_links(sub)) == ["tabletop_010002"]
    # nothing was written inside the scenes through the links
    for scene in (root / "data" / "train128").iterdir():
        assert sorted(p.name for p in scene.iterdir()) == ["transforms.json"]


def test_scene_subset_side_by_side_runs_never_see_a_missing_scene(root: Path) -> None:
    """Two subsets built at once while a reader lists the folder: the reader always finds
    every scene (the old rm -rf + rebuild left it empty or half-built for a moment)."""
    assert _bash(root, 'scene_subset data/sub "10000-10002"').returncode == 0
    r = _bash(
        root,
        """
        for i in $(seq 20); do scene_subset data/sub "10000-10002" & done
        for i in $(seq 200); do
          n=$(ls data/sub 2>/dev/null | wc -l)
          [ "$n" -eq 3 ] || { echo "saw $n scenes" >&2; exit 1; }
        done
        wait
        """,
    )
    assert r.returncode == 0, r.stderr
    assert sorted(_links(root / "data" / "sub")) == [
        "open_010000",
        "room_010001",
        "tabletop_010002",
    ]


def _run_script(root: Path, name: str, env: dict[str, str], *args: str):
    """Run scripts/NAME from a copy of scripts/ under ``root`` (the scripts cd to their
    parent), with PROSPLAT=echo so the training command is printed, not run."""
    shutil.copytree(SCRIPTS, root / "scripts", dirs_exist_ok=True)
    (root / "runs").mkdir(exist_ok=True)
    (root / "runs" / "generator_v7.safetensors").write_bytes(b"")  # shipped_before keeps it
    return subprocess.run(
        ["bash", str(root / "scripts" / name), *args],
        cwd=root,
        env={"PATH": "/usr/bin:/bin", "PROSPLAT": "echo", **env},
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_generator_v8_trains_on_the_scenes_asked_for(root: Path) -> None:
    r = _run_script(
        root, "train_generator_v8.sh", {"SCENES": "10000-10001", "SUBSET": "data/sub8"}, "10"
    )
    assert r.returncode == 0, r.stderr
    args = r.stdout.split()
    assert args[:2] == ["train", "generator"]
    assert args[args.index("--data") + 1] == "data/sub8"
    assert args[args.index("--steps") + 1] == "10"
    assert args[args.index("--ema") + 1] == "0.998"
    assert args[args.index("--frame-prob") + 1] == "0.5"
    assert sorted(_links(root / "data" / "sub8")) == ["open_010000", "room_010001"]


def test_generator_v8_default_scenes_are_v7s(root: Path) -> None:
    """Without SCENES the run asks for v7's 420 scenes (seeds 10000-10359 + hard rounds),
    so on the fake set it stops at the first missing seed and builds no subset."""
    r = _run_script(root, "train_generator_v8.sh", {}, "10")
    assert r.returncode != 0
    assert "no scene with seed 10003" in r.stderr
    assert not (root / "data" / "gen_v6").exists()


@pytest.mark.parametrize("arm, fill", [("fill", True), ("ctrl", False)])
def test_stage2_v16_arms_differ_only_by_the_fill(root: Path, arm: str, fill: bool) -> None:
    """ARM=fill fine-tunes v13 with --fill, ARM=ctrl the same without it: same sets, same
    recipe, each in its own run folder; another ARM is refused before any work."""
    (root / "runs" / "s2v16").mkdir(parents=True)
    (root / "runs" / "s2v16" / "v13.safetensors").write_bytes(b"")  # shipped_before keeps it
    r = _run_script(root, "train_stage2_v16.sh", {"ARM": arm}, "7")
    assert r.returncode == 0, r.stderr
    train = next(line.split() for line in r.stdout.splitlines() if "train improve" in line)
    assert train[train.index("--init") + 1] == "runs/s2v16/v13.safetensors"
    assert train[train.index("--out") + 1] == f"runs/s2v16/{arm}"
    assert train[train.index("--steps") + 1] == "7"
    assert train[train.index("--lpips-weight") + 1] == "0.5"
    sets = train[train.index("--data") + 1].split(",")
    assert sets == ["runs/s2v16/sets/raw64.safetensors", "runs/s2v16/sets/raw128.safetensors"]
    assert ("--fill" in train) == fill and "--alpha" in train and "--warp" in train
    bad = _run_script(root, "train_stage2_v16.sh", {"ARM": "both"})
    assert bad.returncode == 1 and "ARM must be fill or ctrl" in bad.stderr


def test_stage2_v17_curates_half_size_splats_of_its_subset_then_runs_v16s_fill_recipe(
    root: Path,
) -> None:
    """v17: the subset's scenes curated with --splat-scale 0.5 into runs/s2v17/sets, then
    v16's fill arm at LPIPS weight 0.1 from v13 on those sets."""
    (root / "runs" / "s2v16").mkdir(parents=True)
    (root / "runs" / "s2v16" / "v13.safetensors").write_bytes(b"")
    r = _run_script(root, "train_stage2_v17.sh", {"SCENES": "10000-10001 20000-20000"}, "9")
    assert r.returncode == 0, r.stderr
    lines = [line.split() for line in r.stdout.splitlines()]
    curates = [a for a in lines if a[:2] == ["train", "curate"]]
    assert {a[a.index("--out") + 1] for a in curates} == {
        "runs/s2v17/sets/raw64.safetensors", "runs/s2v17/sets/raw128.safetensors",
    }  # fmt: skip
    for a in curates:
        assert a[a.index("--data") + 1] == "data/s2v16_scenes"
        assert a[a.index("--splat-scale") + 1] == "0.5"
    train = next(a for a in lines if a[:2] == ["train", "improve"])
    assert train[train.index("--init") + 1] == "runs/s2v16/v13.safetensors"
    assert train[train.index("--out") + 1] == "runs/s2v17/run"
    assert train[train.index("--lpips-weight") + 1] == "0.1" and "--fill" in train
    assert train[train.index("--data") + 1].split(",") == [
        "runs/s2v17/sets/raw64.safetensors", "runs/s2v17/sets/raw128.safetensors",
    ]  # fmt: skip
    assert sorted(_links(root / "data" / "s2v16_scenes")) == [
        "near_far_020000", "open_010000", "room_010001",
    ]  # fmt: skip
