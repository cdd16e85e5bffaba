"""The shipped weights' recipes (prosplat.train.recipes): their last stages are what the old
script chains passed for the shipped files, their listed commands rebuild every stage, and a
recipe runs end to end (steps and data shrunk) into one resumable folder."""

from __future__ import annotations

import json
import shlex
from dataclasses import replace
from pathlib import Path

import pytest
from synthetic_scenes import write_synthetic_scene

from prosplat.cli import build_parser, main
from prosplat.cli.config_args import config_from_args
from prosplat.core.checkpoints import read_checkpoint
from prosplat.generator.config import GeneratorConfig, preset
from prosplat.train.common import weights_step
from prosplat.train.generator_config import TrainConfig
from prosplat.train.improve import ImproveTrainConfig
from prosplat.train.recipe import Blend, Recipe, RunPaths, Stage, final_config, resolved_config
from prosplat.train.recipes import GENERATOR_TINY, IMPROVE_TINY, RECIPES, run

WEIGHTS = Path(__file__).resolve().parents[2] / "prosplat" / "weights"
PATHS = ("data", "out", "init", "val")

#: What scripts/train_generator_v16.sh ran (git show 9250853:scripts/train_generator_v16.sh):
#: it exec'd train_generator_v8.sh (FRAME_PROB 0.5, EMA 0.998, GROW_ALEXNET=0), which exec'd
#: train_generator_v6.sh with SEED=12, 3,500 steps and v16's own EXTRA_ARGS last.
V16_ARGV = (
    "--data data/gen_v6 --init runs/generator_v14a.safetensors --out runs/gen_v16a --steps 3500 "
    "--sizes 64,128 --any-view --inputs 2,3,4,5,6 --targets 2 --lr 1.5e-4 "
    "--input-depth-weight 1 --depth-weight 0.1 --depth-loss log --input-render-weight 0.5 "
    "--target-scale 2 --warmup 100 --save-every 250 --log-every 50 --cache-scenes 512 --seed 12 "
    "--frame-prob 0.5 --ema 0.998 --input-render-weight 2 --fill-holes"
)


def _parsed(command: str, cls):
    """The config a `prosplat train ...` command line builds."""
    args = build_parser().parse_args(shlex.split(command))
    return config_from_args(cls, args)


def _without_paths(cfg):
    return replace(cfg, **{k: getattr(type(cfg)(data="", out=""), k) for k in PATHS})


def test_generator_tiny_ends_with_what_the_scripts_passed_for_the_shipped_file():
    shipped = _parsed("train generator " + V16_ARGV, TrainConfig)
    final = final_config(GENERATOR_TINY)
    assert _without_paths(final) == _without_paths(shipped)
    assert GENERATOR_TINY.final.init == "v14" and final.init == "v14/checkpoint.safetensors"
    # and with what the shipped file records of its own training
    _, meta = read_checkpoint(WEIGHTS / "generator_tiny.safetensors", "generator")
    ema = json.loads(meta["ema"])
    assert ema == {"decay": final.ema, "updates": final.steps} and int(meta["step"]) == final.steps
    assert int(meta["trained_size"]) == max(final.size_choices)


def test_generator_tiny_grows_the_shipped_network_from_its_first_preset():
    config = preset(GENERATOR_TINY.stages[0].config.config)
    for stage in GENERATOR_TINY.stages:
        c = stage.config
        grown = dict(
            fine_matching_channels=c.grow_fine_matching, alexnet_layers=c.grow_alexnet,
            image_matching_window=c.grow_image_matching, band_candidates=c.grow_band,
        )  # fmt: skip
        config = replace(config, **{k: v for k, v in grown.items() if v})
    _, meta = read_checkpoint(WEIGHTS / "generator_tiny.safetensors", "generator")
    assert config == GeneratorConfig.from_json(meta["config"])


def test_improve_tiny_ends_with_the_command_the_shipped_file_records():
    _, meta = read_checkpoint(WEIGHTS / "improve_tiny.safetensors", "improvement")
    recorded = ImproveTrainConfig(**json.loads(meta["command"].split(" ", 3)[3]))
    final = final_config(IMPROVE_TINY)
    assert _without_paths(final) == _without_paths(recorded)
    # the same curated sets in the same order, and the same start
    names = [Path(p).stem for p in recorded.data.split(",")]
    assert [c.name.split("-", 1)[1] for c in IMPROVE_TINY.final.sets] == names
    assert IMPROVE_TINY.final.init == "v19" and int(meta["steps"]) == final.steps


@pytest.mark.parametrize("recipe", list(RECIPES.values()), ids=list(RECIPES))
def test_each_listed_command_rebuilds_its_stage(recipe):
    paths = RunPaths(Path("runs") / recipe.name)
    from prosplat.train.recipe import stage_commands

    for stage in recipe.stages:
        if isinstance(stage.config, Blend):
            continue
        command = stage_commands(recipe, stage, paths)[-1]
        assert command.startswith(f"prosplat train {stage.kind} ")
        cls = type(stage.config)
        assert _parsed(command.removeprefix("prosplat "), cls) == resolved_config(
            recipe, stage, paths
        ), stage.name


def test_stages_start_from_earlier_stages_only():
    cfg = GENERATOR_TINY.stages[0].config
    with pytest.raises(ValueError, match="not an earlier stage"):
        Recipe("x", "generator", "x.safetensors", "", (Stage("a", cfg, init="b"),))
    with pytest.raises(ValueError, match="no stage 'v99'"):
        GENERATOR_TINY.stage("v99")


def test_the_cli_lists_a_recipe_and_refuses_what_it_would_not_use(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["train", "generator", "--recipe", "generator-tiny", "--list", "--out", "r/g"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert "v16: from v14, seed 12, 3500 steps" in text
    assert "prosplat scenes render --seed 10000" in text
    assert "cp r/g/v16/checkpoint.safetensors prosplat/weights/generator_tiny.safetensors" in text
    with pytest.raises(SystemExit) as done:
        main(["train", "recipes", "improve-tiny"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert (
        "prosplat train generator --recipe generator-tiny --out runs/generator-tiny --until v16"
        in text
    )
    assert "prosplat train blend runs/improve-tiny/v10/improve.safetensors" in text
    for argv, message in (
        (["--lr", "1e-3"], "--lr would not be used"),
        ([], "needs --out"),
    ):
        with pytest.raises(SystemExit) as done:
            main(["train", "generator", "--recipe", "generator-tiny", *argv])
        assert done.value.code == 2 and message in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(["train", "generator", "--out", str(tmp_path / "o")])
    assert done.value.code == 2 and "required: --data" in capsys.readouterr().err


def test_a_recipe_without_its_scenes_names_the_commands_that_render_them(tmp_path, capsys):
    argv = ["train", "generator", "--recipe", "generator-tiny", "--out", str(tmp_path / "run")]
    with pytest.raises(SystemExit) as done:
        main([*argv, "--data-root", str(tmp_path / "data")])
    err = capsys.readouterr().err
    assert done.value.code == 2
    assert "prosplat scenes render --seed 0 --count 60 --size 64" in err and "train64" in err


# ---- runs, steps and data shrunk ----------------------------------------------------------


@pytest.fixture(scope="module")
def small_scenes(tmp_path_factory):
    """Two 32-px scenes of 9 views (5 inputs): enough for the first stages, which train at the
    data's size (curation resizes them to each set's size)."""
    root = tmp_path_factory.mktemp("recipe_scenes_32")
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=9)
    return root


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Two 128-px scenes of 9 views: enough for every stage's sizes and views (~45 s to make)."""
    root = tmp_path_factory.mktemp("recipe_scenes_128")
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=128, n_views=9)
    return root


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one thread is faster


def test_a_recipe_runs_its_stages_into_one_folder_and_skips_those_done(small_scenes, tmp_path):
    out, lines = tmp_path / "generator-tiny", []
    final = run("generator-tiny", out, until="v1", steps=2, scenes=small_scenes, progress=False,
                log=lines.append)  # fmt: skip
    assert final == out / "v1" / "checkpoint.safetensors" and weights_step(final) == 2
    assert lines == ["generator-tiny/v0: training", "generator-tiny/v1: training"]
    cfg = json.loads((out / "v1" / "train_config.json").read_text())
    assert cfg["init"] == str(out / "v0" / "checkpoint.safetensors")
    assert cfg["data"] == str(small_scenes) and cfg["inputs"] == [2, 4]
    before = final.stat().st_mtime_ns
    lines.clear()
    run("generator-tiny", out, until="v1", steps=2, scenes=small_scenes, progress=False,
        log=lines.append)  # fmt: skip
    assert all(": done (" in line for line in lines) and final.stat().st_mtime_ns == before


def test_a_stage_2_recipe_curates_with_its_generator_stage_and_resumes_a_run(
    small_scenes, tmp_path
):
    out = tmp_path / "improve-tiny"
    final = run("improve-tiny", out, until="v4", steps=1, scenes=small_scenes, progress=False,
                log=lambda line: None)  # fmt: skip
    # the sets were curated with generator-tiny's v1, run beside it
    assert (tmp_path / "generator-tiny" / "v1" / "checkpoint.safetensors").is_file()
    assert not (tmp_path / "generator-tiny" / "v2").exists()
    _, meta = read_checkpoint(out / "sets" / "v4-ref64.safetensors", "curated")
    assert "generator-tiny/v1/checkpoint.safetensors" in meta["command"]
    assert meta["refine_steps"] == "1" and meta["depth_sweep"] == "off"
    # v4 went on with v4a's run: its optimiser and step, to a longer schedule
    assert weights_step(out / "v4a" / "improve.safetensors", key="steps") == 1
    assert weights_step(final, key="steps") == 2
    assert (out / "v4" / "train_config.before_1.json").is_file()
    steps = [json.loads(x)["step"] for x in (out / "v4" / "log.jsonl").read_text().splitlines()]
    assert steps == sorted(steps)


@pytest.mark.slow
def test_both_recipes_end_to_end_make_the_shipped_networks(scenes, tmp_path):
    """Every stage of both recipes, one step each (about 2 min on one thread): the files have
    the shipped files' networks and settings."""
    generator = run("generator-tiny", tmp_path / "generator-tiny", steps=1, scenes=scenes,
                    progress=False, log=lambda line: None)  # fmt: skip
    improver = run("improve-tiny", tmp_path / "improve-tiny", steps=1, scenes=scenes,
                   progress=False, log=lambda line: None)  # fmt: skip
    for made, shipped, what in (
        (generator, "generator_tiny.safetensors", "generator"),
        (improver, "improve_tiny.safetensors", "improvement"),
    ):
        a = read_checkpoint(made, what)[1]
        b = read_checkpoint(WEIGHTS / shipped, what)[1]
        assert json.loads(a["config"]) == json.loads(b["config"])
        assert a["parameters"] == b["parameters"]
