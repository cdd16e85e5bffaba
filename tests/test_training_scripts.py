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


def test_hard_rounds_lists_the_rounds_asked_for(root: Path) -> None:
    """Round r of hard scenes is seeds 20000 + 100 kind + 2r and + 2r + 1, six kinds."""
    r = _bash(root, "hard_rounds 2; echo; hard_rounds 4 2")
    assert r.returncode == 0, r.stderr
    first, later = r.stdout.splitlines()
    assert first.split() == [f"20{k}00-20{k}03" for k in range(6)]
    assert later.split() == [f"20{k}04-20{k}07" for k in range(6)]


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


def _flag(args: list[str], flag: str) -> str:
    """The value after ``flag``'s last occurrence: the one the training command takes (a
    script's EXTRA_ARGS come after its recipe and override it)."""
    return args[len(args) - 1 - args[::-1].index(flag) + 1]


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


@pytest.mark.parametrize(
    ("script", "out", "seed", "threads", "first_missing"),
    [
        ("train_generator_v17.sh", "runs/gen_v17a", "13", "1", "10003"),
        ("train_generator_v17b.sh", "runs/gen_v17b", "14", "2", "10420"),
        ("train_generator_v19.sh", "runs/gen_v19", "19", "2", "10003"),
    ],
)
def test_generator_v17_and_v17b_go_on_from_v16_with_its_fill_recipe(
    root: Path, script: str, out: str, seed: str, threads: str, first_missing: str
) -> None:
    """v17 runs v8's script from the shipped v16 (runs/generator_v16.safetensors, kept when
    present) with v16's flags (--fill-holes, the input term at 2), batch seed 13, one thread,
    into runs/gen_v17a; v17b is v17 with batch seed 14 on two threads into runs/gen_v17b. By
    default v17 asks for the 527 scenes of rounds 0-6 and v17b for rounds 7-8 only (from seed
    10420), so on the fake set each stops at its first missing seed (v17b at none of rounds
    0-6). v19 is v17 with batch seed 19 on two threads on all 28 rounds (2,016 scenes)."""
    (root / "runs").mkdir(exist_ok=True)
    (root / "runs" / "generator_v16.safetensors").write_bytes(b"")  # shipped_before keeps it
    fake_echo = root / "echo_threads"
    fake_echo.write_text('#!/usr/bin/env bash\necho "OMP=$OMP_NUM_THREADS $*"\n')
    fake_echo.chmod(0o755)
    env = {"SCENES": "10000-10001", "SUBSET": "data/sub17", "PROSPLAT": str(fake_echo)}
    r = _run_script(root, script, env, "12")
    assert r.returncode == 0, r.stderr
    args = r.stdout.split()
    expect = {"--init": "runs/generator_v16.safetensors", "--out": out,
              "--seed": seed, "--steps": "12", "--data": "data/sub17",
              "--input-render-weight": "2"}  # fmt: skip
    assert {flag: _flag(args, flag) for flag in expect} == expect
    assert "--fill-holes" in args and args[0] == f"OMP={threads}"
    default = _run_script(root, script, {}, "12")
    assert default.returncode != 0 and f"no scene with seed {first_missing}" in default.stderr


def test_generator_v9_starts_from_v8_with_v8s_recipe(root: Path) -> None:
    """v9 runs v8's script from the shipped v8 (runs/generator_v8.safetensors, kept when
    present) into runs/gen_v9 with batch seed 3."""
    (root / "runs").mkdir(exist_ok=True)
    (root / "runs" / "generator_v8.safetensors").write_bytes(b"")  # shipped_before keeps it
    r = _run_script(
        root, "train_generator_v9.sh", {"SCENES": "10000-10001", "SUBSET": "data/sub9"}, "12"
    )
    assert r.returncode == 0, r.stderr
    args = r.stdout.split()
    assert args[args.index("--init") + 1] == "runs/generator_v8.safetensors"
    assert args[args.index("--out") + 1] == "runs/gen_v9"
    assert args[args.index("--seed") + 1] == "3"
    assert args[args.index("--steps") + 1] == "12"
    assert args[args.index("--ema") + 1] == "0.998"
    assert args[args.index("--data") + 1] == "data/sub9"


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


def test_stage2_v22_curates_v16as_capped_renders_of_unseen_scenes_then_fine_tunes_v19(
    root: Path,
) -> None:
    """v22: raw64, raw128 and ref64 of the subset curated with the generator asked for (the
    cap at its default), then v19's recipe at lr 5e-5 from v19 on the three sets; a missing
    generator stops the run before any work."""
    (root / "runs" / "s2v22").mkdir(parents=True)
    (root / "runs" / "s2v22" / "v19.safetensors").write_bytes(b"")  # shipped_before keeps it
    (root / "runs" / "g.safetensors").write_bytes(b"")
    env = {"SCENES": "10000-10001 20000-20000", "GEN": "runs/g.safetensors"}
    r = _run_script(root, "train_stage2_v22.sh", env, "9")
    assert r.returncode == 0, r.stderr
    lines = [line.split() for line in r.stdout.splitlines()]
    curates = {a[a.index("--out") + 1]: a for a in lines if a[:2] == ["train", "curate"]}
    sets = [f"runs/s2v22/sets/{name}.safetensors" for name in ("raw64", "raw128", "ref64")]
    assert sorted(curates) == sorted(sets)
    for a in curates.values():
        assert a[a.index("--data") + 1] == "data/s2v22_scenes"
        assert a[a.index("--generator") + 1] == "runs/g.safetensors"
        assert a[a.index("--generator-size") + 1] == "128"
        assert "--max-splat-radius" not in a  # the default, as enhanced views are rendered
    assert curates[sets[2]][curates[sets[2]].index("--refine-steps") + 1] == "100"
    train = next(a for a in lines if a[:2] == ["train", "improve"])
    assert train[train.index("--init") + 1] == "runs/s2v22/v19.safetensors"
    assert train[train.index("--out") + 1] == "runs/s2v22/run"
    assert train[train.index("--data") + 1].split(",") == sets
    assert train[train.index("--lr") + 1] == "5e-5" and train[train.index("--steps") + 1] == "9"
    assert {"--fill", "--warp", "--alpha", "--subpixel-shift"} <= set(train)
    assert sorted(_links(root / "data" / "s2v22_scenes")) == [
        "near_far_020000", "open_010000", "room_010001",
    ]  # fmt: skip
    missing = _run_script(root, "train_stage2_v22.sh", {"GEN": "runs/none.safetensors"})
    assert missing.returncode == 1 and "no generator runs/none.safetensors" in missing.stderr


def test_stage2_v23_runs_v22s_recipe_from_v22_on_v17as_renders_of_unseen_scenes(
    root: Path,
) -> None:
    """v23: v22's script from the shipped v22 (runs/s2v23/v22.safetensors, kept when present)
    on generator v17a's checkpoint, into runs/s2v23; by default it asks for the scenes v17a
    never saw (from seed 10443), so on the fake set it stops at the first missing seed."""
    (root / "runs" / "s2v23").mkdir(parents=True)
    (root / "runs" / "s2v23" / "v22.safetensors").write_bytes(b"")
    (root / "runs" / "gen_v17a").mkdir()
    (root / "runs" / "gen_v17a" / "checkpoint.safetensors").write_bytes(b"")
    r = _run_script(root, "train_stage2_v23.sh", {"SCENES": "10000-10001"}, "7")
    assert r.returncode == 0, r.stderr
    lines = [line.split() for line in r.stdout.splitlines()]
    curates = [a for a in lines if a[:2] == ["train", "curate"]]
    assert len(curates) == 3
    assert {_flag(a, "--generator") for a in curates} == {"runs/gen_v17a/checkpoint.safetensors"}
    assert {_flag(a, "--data") for a in curates} == {"data/s2v23_scenes"}
    assert all(_flag(a, "--out").startswith("runs/s2v23/sets/") for a in curates)
    train = next(a for a in lines if a[:2] == ["train", "improve"])
    expect = {"--init": "runs/s2v23/v22.safetensors", "--out": "runs/s2v23/run",
              "--steps": "7", "--lr": "5e-5"}  # fmt: skip
    assert {flag: _flag(train, flag) for flag in expect} == expect
    assert sorted(_links(root / "data" / "s2v23_scenes")) == ["open_010000", "room_010001"]
    default = _run_script(root, "train_stage2_v23.sh", {}, "7")
    assert default.returncode != 0 and "no scene with seed 10443" in default.stderr


def test_stage2_v24_adds_refined_128px_renders_of_unseen_scenes_to_v22s_sets(
    root: Path,
) -> None:
    """v24: v22's script from the shipped v22 on the shipped v16 (both taken from git
    history into runs/s2v24, kept when present) with a fourth set, ref128 (4 inputs, refined
    100 steps at 128 px); the two curation processes share the four sets and training takes
    all four in order. By default it asks for seeds from 10443 (neither model saw them)."""
    (root / "runs" / "s2v24").mkdir(parents=True)
    for name in ("v22", "v16"):
        (root / "runs" / "s2v24" / f"{name}.safetensors").write_bytes(b"")
    r = _run_script(root, "train_stage2_v24.sh", {"SCENES": "10000-10001"}, "7")
    assert r.returncode == 0, r.stderr
    lines = [line.split() for line in r.stdout.splitlines()]
    curates = {_flag(a, "--out"): a for a in lines if a[:2] == ["train", "curate"]}
    names = ("raw64", "raw128", "ref64", "ref128")
    sets = [f"runs/s2v24/sets/{name}.safetensors" for name in names]
    assert sorted(curates) == sorted(sets)
    expect = {  # views, size, refine steps
        "raw64": ("2,4", "64", "0"), "raw128": ("4", "128", "0"),
        "ref64": ("2,4", "64", "100"), "ref128": ("4", "128", "100"),
    }  # fmt: skip
    for name, path in zip(names, sets, strict=True):
        a = curates[path]
        assert (_flag(a, "--views"), _flag(a, "--size"), _flag(a, "--refine-steps")) == expect[name]
        assert _flag(a, "--generator") == "runs/s2v24/v16.safetensors"
        assert _flag(a, "--data") == "data/s2v24_scenes"
    train = next(a for a in lines if a[:2] == ["train", "improve"])
    assert _flag(train, "--data").split(",") == sets
    assert _flag(train, "--init") == "runs/s2v24/v22.safetensors"
    assert _flag(train, "--out") == "runs/s2v24/run" and _flag(train, "--steps") == "7"
    default = _run_script(root, "train_stage2_v24.sh", {}, "7")
    assert default.returncode != 0 and "no scene with seed 10443" in default.stderr


def test_render_v2_data_train_renders_only_the_rounds_asked_for(root: Path) -> None:
    """`render_v2_data.sh train 9 7` starts prosplat for rounds 7 and 8 only: 60 family seeds
    from 10000 + 60·round and two seeds of each hard scene from 20000 + 100·kind + 2·round."""
    r = _run_script(root, "render_v2_data.sh", {}, "train", "9", "7")
    assert r.returncode == 0, r.stderr
    calls = [line.split() for line in r.stdout.splitlines()]
    assert all(a[:2] == ["scenes", "render"] for a in calls)
    family = [(_flag(a, "--seed"), _flag(a, "--count")) for a in calls if "--scene" not in a]
    assert family == [("10420", "60"), ("10480", "60")]
    hard = sorted(int(_flag(a, "--seed")) for a in calls if "--scene" in a)
    assert hard == sorted(20000 + 100 * k + 2 * r for k in range(6) for r in (7, 8))
    assert {_flag(a, "--denoise-quality") for a in calls} == {"fast"}


def _run_gpu_script(cmd: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    """A GPU script run here with its python faked (the FAKE_*PY texts below)."""
    return subprocess.run(
        cmd, cwd=SCRIPTS.parent, env=env, capture_output=True, text=True, timeout=120
    )


FAKE_PY = """#!/usr/bin/env bash
# gpu_train_stage2.sh's python: pip and the prosplat training commands are recorded and faked
# (curate writes its --out, improve a log of 20 steps in 10 s), the rest runs for real
echo "$*" >> "$CALLS"
[ "$1 $2" = "-m pip" ] && exit 0
if [ "$1 $2 $3" = "-m prosplat train" ]; then
  args=("$@")
  for ((i = 0; i < $#; i++)); do [ "${args[$i]}" = --out ] && out=${args[$((i + 1))]}; done
  if [ "$4" = curate ]; then touch "$out"; echo "curated set: $out"; exit 0; fi
  mkdir -p "$out"
  printf '{"step": 20, "seconds": 1.0}\\n{"step": 40, "seconds": 11.0}\\n' > "$out/log.jsonl"
  touch "$out/improve.safetensors"
  exit 0
fi
exec "$REAL_PY" "$@"
"""


def test_gpu_stage2_curates_in_slices_then_trains_for_the_time_left(tmp_path: Path) -> None:
    """scripts/gpu_train_stage2.sh with its python faked: every scene of the pack is curated
    once per set, in SHARDS slices with each set's views, size and refinement; the probe's
    step time sets the step count; the options reach both runs; a second call on the warm
    machine curates nothing again."""
    import sys

    from synthetic_scenes import write_synthetic_scene

    from prosplat.data.packed import pack_scenes

    for k in range(5):
        write_synthetic_scene(tmp_path / "scenes" / f"s{k}", size=16, n_views=3)
    pack = pack_scenes(sorted((tmp_path / "scenes").iterdir()), tmp_path / "p.npz", depth=False)
    fake = tmp_path / "fakepy"
    fake.write_text(FAKE_PY)
    fake.chmod(0o755)
    calls = tmp_path / "calls.txt"
    env = {
        "PATH": "/usr/bin:/bin", "PY": str(fake), "REAL_PY": sys.executable, "CALLS": str(calls),
        "PACKS": str(pack), "SHARDS": "2", "WORK": str(tmp_path / "w"), "OUT": str(tmp_path / "o"),
        "SETS": "raw64:2,3:64:0 ref64:2:64:300",
    }  # fmt: skip
    cmd = ["bash", str(SCRIPTS / "gpu_train_stage2.sh"), "10000", "--crop", "48", "--fill"]
    run = _run_gpu_script(cmd, env)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = [line.split() for line in calls.read_text().splitlines()]
    curates = [a for a in lines if a[:4] == ["-m", "prosplat", "train", "curate"]]
    got = {(a[a.index("--out") + 1].split("/")[-1], a[a.index("--views") + 1],
            a[a.index("--refine-steps") + 1], a[a.index("--first") + 1], a[a.index("--count") + 1])
           for a in curates}  # fmt: skip
    assert got == {
        ("raw64_0.safetensors", "2,3", "0", "0", "3"), ("raw64_1.safetensors", "2,3", "0", "3", "3"),
        ("ref64_0.safetensors", "2", "300", "0", "3"), ("ref64_1.safetensors", "2", "300", "3", "3"),
    }  # fmt: skip
    assert all(a[a.index("--data") + 1] == str(pack) for a in curates)
    assert not any("--generator" in a for a in curates)  # the shipped generator by default
    probe, train = [a for a in lines if a[:4] == ["-m", "prosplat", "train", "improve"]]
    assert probe[probe.index("--steps") + 1] == "60"
    # 0.5 s a step, 80 % of the ~9,950 s left: 15,800-15,900 steps, in hundreds
    assert int(train[train.index("--steps") + 1]) in (15800, 15900)
    sets = train[train.index("--data") + 1].split(",")
    assert [s.split("/")[-1] for s in sets] == [
        "raw64_0.safetensors",
        "raw64_1.safetensors",
        "ref64_0.safetensors",
        "ref64_1.safetensors",
    ]
    for a in (probe, train):
        assert a[a.index("--device") + 1] == "cuda" and "--fill" in a
        assert a[a.index("--init") + 1] == "prosplat/weights/improve_tiny.safetensors"
    assert {p.name for p in (tmp_path / "o").iterdir()} == {
        "improve.safetensors",
        "log.jsonl",
        "logs.tgz",
    }
    calls.write_text("")
    again = _run_gpu_script(cmd, env)
    assert again.returncode == 0, again.stderr
    assert "train curate" not in calls.read_text()
    # a candidate generator's renders, curated afresh in another WORK folder
    env = {**env, "GENERATOR": ".gpu/gen v8.safetensors", "WORK": str(tmp_path / "w2")}
    other = _run_gpu_script(cmd, env)
    assert other.returncode == 0, other.stdout + other.stderr
    curates = [line for line in calls.read_text().splitlines() if "train curate" in line]
    assert len(curates) == 4
    assert all("--generator .gpu/gen v8.safetensors --size" in c for c in curates)


FAKE_GENERATOR_PY = """#!/usr/bin/env bash
# gpu_train_generator.sh's python: pip, the LPIPS unpacking and `train generator` are recorded
# and faked (a run logs steps 10 and 30 at 1 s and 11 s: 0.5 s a step, and saves a checkpoint
# whose step the resume check reads), the rest runs for real
echo "$*" >> "$CALLS"
[ "$1 $2" = "-m pip" ] && exit 0
[ "$1" = scripts/gpu_lpips.py ] && exit 0
if [ "$1 $2 $3 $4" = "-m prosplat train generator" ]; then
  args=("$@")
  for ((i = 0; i < $#; i++)); do
    [ "${args[$i]}" = --out ] && out=${args[$((i + 1))]}
    [ "${args[$i]}" = --steps ] && steps=${args[$((i + 1))]}
  done
  mkdir -p "$out"
  printf '{"step": 10, "seconds": 1.0}\\n{"step": 30, "seconds": 11.0}\\n' > "$out/log.jsonl"
  echo "$steps" > "$out/checkpoint.safetensors"
  exit 0
fi
if [ "$1" = -c ] && [[ "$2" == *weights_step* ]]; then
  f=$(sed -n "s/.*w('\\(.*\\)').*/\\1/p" <<< "$2"); cat "$f" 2> /dev/null || echo 0; exit 0
fi
exec "$REAL_PY" "$@"
"""


def test_gpu_generator_probes_then_trains_every_run_for_the_time_left(tmp_path: Path) -> None:
    """scripts/gpu_train_generator.sh with its python faked: every run is probed, then trained
    with its own options for the steps the probe's rate leaves time for, on every pack; a warm
    machine's second call adds its steps to the run it resumes; what comes back is named."""
    import sys

    carry = tmp_path / "carry"
    carry.mkdir()
    for name in ("train_000.npz", "train_001.npz"):
        (carry / name).touch()
    fake = tmp_path / "fakepy"
    fake.write_text(FAKE_GENERATOR_PY)
    fake.chmod(0o755)
    calls = tmp_path / "calls.txt"
    env = {
        "PATH": "/usr/bin:/bin", "PY": str(fake), "REAL_PY": sys.executable, "CALLS": str(calls),
        "CARRY": str(carry), "GSPLAT": "0", "WORK": str(tmp_path / "w"), "OUT": str(tmp_path / "o"),
    }  # fmt: skip
    cmd = ["bash", str(SCRIPTS / "gpu_train_generator.sh"), "1000",
           "a", "--batch 8 --seed 1", "b", "--batch 8 --input-render-weight 2"]  # fmt: skip
    run = _run_gpu_script(cmd, env)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = [line.split() for line in calls.read_text().splitlines()]
    trains = [a for a in lines if a[:4] == ["-m", "prosplat", "train", "generator"]]
    assert len(trains) == 4
    for a in trains:
        assert a[a.index("--data") + 1] == f"{carry}/train_000.npz,{carry}/train_001.npz"
        assert a[a.index("--device") + 1] == "cuda" and a[a.index("--batch") + 1] == "8"
    probes = [a for a in trains if "/probe_" in a[a.index("--out") + 1]]
    assert sorted(a[a.index("--steps") + 1] for a in probes) == ["30", "30"]
    runs = {a[a.index("--out") + 1].split("/")[-1]: a for a in trains if a not in probes}
    assert "--input-render-weight" in runs["b"] and "--seed" in runs["a"]
    # 0.5 s a step, 90 % of the ~960 s left after the probe: about 1,700 steps, in fifties
    steps = int(runs["a"][runs["a"].index("--steps") + 1])
    assert 1600 <= steps <= 1750 and steps % 50 == 0
    assert {p.name for p in (tmp_path / "o").iterdir()} == {
        "a_checkpoint.safetensors", "a_log.jsonl", "b_checkpoint.safetensors", "b_log.jsonl",
        "logs.tgz",
    }  # fmt: skip
    calls.write_text("")
    again = _run_gpu_script(cmd, env)
    assert again.returncode == 0, again.stdout + again.stderr
    resumed = [line.split() for line in calls.read_text().splitlines() if "/runs/a " in line]
    assert int(resumed[0][resumed[0].index("--steps") + 1]) > steps  # its steps added


SEEN24 = [f"room_{s:06d}" for s in range(10000, 10018)] + [
    f"{kind}_{20000 + 100 * k:06d}"
    for k, kind in enumerate(
        (
            "textureless",
            "specular",
            "near_far",
            "thin_structures",
            "repeated_pattern",
            "inside_outside",
        )
    )
]


@pytest.mark.parametrize("steps", ["15", "0"])
def test_screen_generator_trains_on_seen_scenes_then_scores_them(tmp_path: Path, steps: str):
    """The screen trains v16's recipe (train_generator_v17.sh, from v16) on the 24 scenes of
    round 0 it links into data/seen24, then scores the run's checkpoint on those same scenes;
    with 0 steps it trains nothing and scores the shipped weights."""
    for name in SEEN24:
        (tmp_path / "data" / "train128" / name).mkdir(parents=True)
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "generator_v16.safetensors").write_bytes(b"")  # shipped_before keeps it
    calls = tmp_path / "calls.txt"
    fake = tmp_path / "fake"
    fake.write_text(f'#!/usr/bin/env bash\necho "$*" >> {calls}\n')
    fake.chmod(0o755)
    env = {"PROSPLAT": str(fake), "PY": str(fake)}
    r = _run_script(tmp_path, "screen_generator.sh", env, "cand", steps)
    assert r.returncode == 0, r.stderr
    lines = calls.read_text().splitlines()
    assert sorted(_links(tmp_path / "data" / "seen24")) == sorted(SEEN24)
    train = [line.split() for line in lines if line.startswith("train generator")]
    ladder = next(line.split() for line in lines if line.startswith("eval ladder"))
    depth = next(line.split() for line in lines if "input_depth.py" in line)
    if steps == "0":
        assert train == []
        weights = "prosplat/weights/generator_tiny.safetensors"
    else:
        (args,) = train
        expect = {"--data": "data/seen24", "--steps": "15", "--out": "runs/screen_cand",
                  "--init": "runs/generator_v16.safetensors"}  # fmt: skip
        assert {flag: _flag(args, flag) for flag in expect} == expect
        weights = "runs/screen_cand/checkpoint.safetensors"
    assert _flag(ladder, "--data") == "data/seen24" and _flag(ladder, "--sizes") == "128"
    assert _flag(ladder, "--generator") == weights
    assert (
        _flag(depth, "--data") == "data/seen24" and _flag(depth, "--generator") == f"cand={weights}"
    )
