"""Training the generator end to end on tiny synthetic scene folders (no Blender)."""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat, cli  # noqa: F401
from prosplat.data import SceneDataset
from prosplat.data.packed import pack_scenes
from prosplat.train.common import (
    WEIGHTS_NAME,
    CheckpointError,
    draw_count,
    load_checkpoint,
    lr_at,
    pick_device,
    save_checkpoint,
    setup_distributed,
    step_indices,
    weights_step,
)
from prosplat.train.generator import train
from prosplat.train.generator_config import TrainConfig, parse_inputs


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=5)
    # exactly 2 inputs and 1 target: every step sees the same batch
    write_synthetic_scene(root.parent / "fixed" / "scene", size=32, n_views=3)
    return root


def test_train_logs_checkpoints_and_resumes(dataset, tmp_path):
    out = tmp_path / "run"
    cfg = TrainConfig(
        data=str(dataset),
        val=str(dataset),
        out=str(out),
        steps=3,
        inputs=2,
        targets=1,
        lpips_weight=0.05,
        depth_weight=0.1,
        log_every=1,
        val_every=3,
        val_scenes=1,
        save_every=2,
        warmup=1,
    )
    ckpt = train(cfg, progress=False)
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3]
    assert all(torch.isfinite(torch.tensor(r["loss"])) for r in log)
    assert "val_psnr" in log[-1] and log[-1]["val_psnr"] > 5
    pipe = ProSplat.from_pretrained(ckpt)
    assert pipe.trained_size == 32  # the data's size: the pipeline runs the weights there
    sc_images = torch.rand(2, 3, 32, 32)
    from prosplat.eval.demo_scene import orbit_cameras

    g = pipe.reconstruct(sc_images, orbit_cameras(2, 32, 32), near=0.5, far=10.0, budget="all")
    assert len(g.gaussians) == 2 * 32 * 32
    # Resume: the same command with more steps continues from step 3, not from scratch.
    more = TrainConfig(**{**cfg.__dict__, "steps": 5})
    train(more, progress=False)
    steps = [json.loads(line)["step"] for line in (out / "log.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4, 5]
    assert torch.load(out / "state.pt", weights_only=True)["step"] == 5


def _fail_render_loss_at(monkeypatch, call: int, error: BaseException | type) -> Callable:
    """Make the training loss raise ``error`` on its ``call``-th call (a Ctrl-C, a crash);
    returns the function that puts the real loss back."""
    import prosplat.train.generator as gen

    real, calls = gen.render_loss, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == call:
            raise error
        return real(*args, **kwargs)

    monkeypatch.setattr(gen, "render_loss", failing)
    return lambda: monkeypatch.setattr(gen, "render_loss", real)


def test_an_interrupted_run_saves_the_step_reached_and_resumes(dataset, tmp_path, monkeypatch):
    """Ctrl-C (or `timeout --signal=INT` on a time-boxed GPU call) between checkpoints keeps
    the steps done: a checkpoint at the step reached, and the same command goes on from it."""
    out = tmp_path / "run"
    cfg = TrainConfig(
        data=str(dataset), out=str(out), steps=5, inputs=2, targets=1, lpips_weight=0.0,
        log_every=1, save_every=10, warmup=1,
    )  # fmt: skip
    restore = _fail_render_loss_at(monkeypatch, 4, KeyboardInterrupt)
    train(cfg, progress=False)
    assert torch.load(out / "state.pt", weights_only=True)["step"] == 3  # none was due (10)
    restore()
    train(cfg, progress=False)
    steps = [json.loads(line)["step"] for line in (out / "log.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4, 5]


def test_a_run_killed_before_its_first_save_starts_over_with_the_same_command(
    dataset, tmp_path, monkeypatch
):
    """A run killed (not interrupted: no save) before its first checkpoint leaves its config
    and log behind; the same command starts it over with a warning and a log that lists each
    step once, and a changed command is refused, naming what changed."""
    out = tmp_path / "run"
    cfg = TrainConfig(
        data=str(dataset), out=str(out), steps=4, inputs=2, targets=1, lpips_weight=0.0,
        log_every=1, save_every=10, warmup=1,
    )  # fmt: skip
    restore = _fail_render_loss_at(monkeypatch, 3, RuntimeError("killed"))
    with pytest.raises(RuntimeError, match="killed"):
        train(cfg, progress=False)
    assert load_checkpoint(out) is None and (out / "log.jsonl").read_text().count("step") == 2
    restore()
    changed = TrainConfig(**{**cfg.__dict__, "lr": cfg.lr * 2})
    with pytest.raises(FileExistsError, match="differs in lr"):
        train(changed, progress=False)
    with pytest.warns(UserWarning, match="before its first checkpoint"):
        train(cfg, progress=False)
    steps = [json.loads(line)["step"] for line in (out / "log.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4] and load_checkpoint(out).step == 4


def test_stop_at_takes_a_run_in_parts_with_the_same_result(dataset, tmp_path):
    """--stop-at 2 then the same run to its end gives the weights (and learning rates) of one
    uninterrupted run: the schedule follows --steps in both."""
    from prosplat.core.checkpoints import read_checkpoint

    base = dict(
        data=str(dataset),
        steps=4,
        inputs=2,
        targets=1,
        lpips_weight=0.0,
        log_every=1,
        save_every=10,
        warmup=1,
    )
    whole = train(TrainConfig(**base, out=str(tmp_path / "whole")), progress=False)
    part = train(TrainConfig(**base, out=str(tmp_path / "parts"), stop_at=2), progress=False)
    assert torch.load(part.parent / "state.pt", weights_only=True)["step"] == 2
    parts = train(TrainConfig(**base, out=str(tmp_path / "parts")), progress=False)
    lrs = [
        [json.loads(line)["lr"] for line in (p.parent / "log.jsonl").read_text().splitlines()]
        for p in (whole, parts)
    ]
    assert lrs[0] == lrs[1] and len(lrs[0]) == 4
    a, b = (read_checkpoint(p, "generator")[0] for p in (whole, parts))
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="stop_at"):
        TrainConfig(**base, out="x", stop_at=0)


def test_training_lowers_the_loss_on_a_fixed_scene(dataset, tmp_path):
    torch.manual_seed(0)
    out = tmp_path / "run"
    cfg = TrainConfig(
        data=str(dataset.parent / "fixed"),
        out=str(out),
        steps=40,
        inputs=2,
        targets=1,
        lpips_weight=0.0,
        log_every=1,
        save_every=40,
        warmup=1,
        lr=1e-3,
    )
    train(cfg, progress=False)
    losses = [json.loads(line)["loss"] for line in (out / "log.jsonl").read_text().splitlines()]
    assert sum(losses[-5:]) / 5 < 0.6 * sum(losses[:5]) / 5


def test_lr_schedule_warms_up_and_decays():
    cfg = TrainConfig(data="", out="", steps=100, warmup=10, lr=1.0)
    assert lr_at(0, cfg) == pytest.approx(0.1) and lr_at(9, cfg) == pytest.approx(1.0)
    assert lr_at(100, cfg) == pytest.approx(0.1) and lr_at(55, cfg) < 1.0


def test_a_run_folder_of_another_run_is_not_overwritten(dataset, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    other = TrainConfig(data="elsewhere", out=str(out), steps=1)
    (out / "train_config.json").write_text(json.dumps(other.__dict__))
    with pytest.raises(FileExistsError, match="another run.*differs in data"):
        train(TrainConfig(data=str(dataset), out=str(out), steps=1), progress=False)


# ---- variable input-view counts --------------------------------------------------------------
def test_inputs_accept_a_count_or_a_set():
    assert parse_inputs("4") == 4 and parse_inputs("6,2,4,2") == (2, 4, 6)
    assert TrainConfig(data="", out="", inputs="2,4,6").view_counts == (2, 4, 6)
    assert TrainConfig(data="", out="", inputs=3).view_counts == (3,)
    assert TrainConfig(data="", out="", inputs=(4, 2)).view_counts == (2, 4)
    with pytest.raises(ValueError, match="2-6"):
        TrainConfig(data="", out="", inputs="2,7")
    with pytest.raises(ValueError, match="comma-separated"):
        TrainConfig(data="", out="", inputs="two")
    with pytest.raises(argparse.ArgumentTypeError, match="2-6"):
        parse_inputs("1")


def test_view_counts_drawn_per_step_cover_the_set_and_follow_the_seed():
    counts = (2, 4, 6)
    seq = [draw_count(counts, seed=0, step=s) for s in range(60)]
    assert set(seq) == {2, 4, 6}
    assert min(seq.count(n) for n in counts) >= 10  # roughly uniform, not stuck on one value
    assert seq == [draw_count(counts, seed=0, step=s) for s in range(60)]
    assert seq != [draw_count(counts, seed=1, step=s) for s in range(60)]
    assert {draw_count((4,), seed=3, step=s) for s in range(10)} == {4}


@pytest.fixture(scope="module")
def wide_dataset(tmp_path_factory):
    """Scenes with 5 input views, so steps can draw 2 or 4 of them."""
    root = tmp_path_factory.mktemp("wide")
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=9)
    return root


def test_training_draws_each_steps_view_count_from_the_set(wide_dataset, tmp_path):
    torch.set_num_threads(1)
    cfg = TrainConfig(
        data=str(wide_dataset),
        out=str(tmp_path / "run"),
        steps=6,
        inputs="2,4",
        targets=1,
        lpips_weight=0.0,
        log_every=1,
        save_every=6,
        warmup=1,
        seed=5,
    )
    train(cfg, progress=False)
    log = _log(tmp_path / "run")
    assert [r["inputs"] for r in log] == [draw_count((2, 4), 5, s) for s in range(6)]
    assert {r["inputs"] for r in log} == {2, 4}


def test_step_indices_shard_one_global_batch_over_ranks():
    n, batch, world = 10, 2, 2
    for step in range(12):
        one = step_indices(n, batch * world, seed=3, step=step)
        ranks = [
            step_indices(n, batch, seed=3, step=step, rank=r, world_size=world) for r in (0, 1)
        ]
        assert ranks[0][0] == ranks[1][0] == one[0]  # the same epoch
        assert ranks[0][1] + ranks[1][1] == one[1]  # rank slices concatenate to the batch
    # An epoch (2 steps of 4 here, the last 2 scenes dropped) never repeats a scene.
    epoch0 = step_indices(n, 4, 3, 0)[1] + step_indices(n, 4, 3, 1)[1]
    assert len(set(epoch0)) == 8
    assert step_indices(n, 4, 3, 2)[0] == 1 and step_indices(n, 4, 3, 2) != step_indices(n, 4, 4, 2)
    with pytest.raises(ValueError, match="cannot fill one step"):
        step_indices(3, 2, 0, 0, world_size=2)


# ---- checkpoints that survive a crash between their two writes -------------------------------
def _weights(value: float) -> dict[str, torch.Tensor]:
    return {"w": torch.full((3,), value)}


def test_load_checkpoint_falls_back_to_the_pair_that_agrees(tmp_path):
    assert load_checkpoint(tmp_path) is None
    save_checkpoint(tmp_path, 1, _weights(1.0), {"x": torch.tensor(1)})
    save_checkpoint(tmp_path, 2, _weights(2.0), {"x": torch.tensor(2)})
    ck = load_checkpoint(tmp_path)
    assert ck.step == 2 and ck.weights["w"][0] == 2.0 and ck.weights_path.name == WEIGHTS_NAME
    # A kill after the old weights moved aside, before the new ones landed: no current file.
    (tmp_path / WEIGHTS_NAME).rename(tmp_path / "checkpoint.prev.safetensors")
    ck = load_checkpoint(tmp_path)
    assert ck.step == 2 and ck.weights["w"][0] == 2.0 and int(ck.state["x"]) == 2


def test_load_checkpoint_refuses_files_without_a_consistent_pair(tmp_path):
    save_checkpoint(tmp_path, 4, _weights(4.0), {})
    (tmp_path / "state.pt").unlink()  # weights of a first save whose state never got written
    with pytest.raises(CheckpointError, match="no state.pt"):
        load_checkpoint(tmp_path)
    torch.save({"step": 9}, tmp_path / "state.pt")  # a state no weights file matches
    with pytest.raises(CheckpointError, match="step 9.*checkpoint.safetensors: step 4"):
        load_checkpoint(tmp_path)


def test_a_crash_between_the_two_writes_resumes_without_mixing_steps(
    dataset, tmp_path, monkeypatch
):
    torch.set_num_threads(1)  # bit-for-bit comparable runs

    def config(out, steps):
        return TrainConfig(
            data=str(dataset),
            out=str(out),
            steps=steps,
            inputs=2,
            targets=1,
            lpips_weight=0.0,
            log_every=1,
            save_every=1,
            warmup=1,
            lr=1e-3,
        )

    straight = load_checkpoint(train(config(tmp_path / "straight", 4), progress=False).parent)
    crashed = tmp_path / "crashed"
    train(config(crashed, 2), progress=False)

    def killed(*args, **kwargs):  # the process dies after the step-3 weights are in place
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", killed)
    with pytest.raises(KeyboardInterrupt):
        train(config(crashed, 4), progress=False)
    monkeypatch.undo()
    assert weights_step(crashed / WEIGHTS_NAME) == 3
    assert torch.load(crashed / "state.pt", weights_only=True)["step"] == 2
    ck = load_checkpoint(crashed)
    assert ck.step == 2 and ck.weights_path.name == "checkpoint.prev.safetensors"

    with pytest.warns(UserWarning, match="interrupted save"):
        train(config(crashed, 4), progress=False)
    assert [r["step"] for r in _log(crashed)] == [1, 2, 3, 4]  # step 3 logged once
    resumed = load_checkpoint(crashed)
    assert resumed.step == 4
    # Data order is a function of (seed, step): the resumed run equals the uninterrupted one.
    for k, v in straight.weights.items():
        torch.testing.assert_close(resumed.weights[k], v, rtol=0, atol=1e-6)


# ---- several processes under torchrun (gloo on the CPU) --------------------------------------
def test_torchrun_two_cpu_processes_equal_one_process_with_twice_the_batch(wide_dataset, tmp_path):
    """2 gloo processes x batch 1 take the same steps as 1 process x batch 2; only rank 0
    writes (one log line per step, one checkpoint pair, nothing half-written)."""
    args = [
        "train", "generator", "--data", str(wide_dataset), "--steps", "3", "--inputs", "2,4",
        "--targets", "1", "--lpips-weight", "0", "--save-every", "2", "--warmup", "1",
        "--log-every", "1", "--device", "cpu",
    ]  # fmt: skip
    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
        + ["-m", "prosplat", *args, "--batch", "1", "--out", str(tmp_path / "ddp")],
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    torch.set_num_threads(1)
    with pytest.raises(SystemExit) as done:
        cli.main([*args, "--batch", "2", "--out", str(tmp_path / "one")])
    assert done.value.code == 0

    ddp, one = tmp_path / "ddp", tmp_path / "one"
    assert [r["step"] for r in _log(ddp)] == [1, 2, 3]
    assert [r["inputs"] for r in _log(ddp)] == [r["inputs"] for r in _log(one)]
    for a, b in zip(_log(ddp), _log(one)):
        assert a["loss"] == pytest.approx(b["loss"], rel=1e-5)  # the mean over both ranks
    assert sorted(p.name for p in ddp.iterdir()) == sorted(
        ["checkpoint.safetensors", "checkpoint.prev.safetensors", "state.pt"]
        + ["log.jsonl", "train_config.json"]
    )
    assert weights_step(ddp / WEIGHTS_NAME) == 3
    pipe = ProSplat.from_pretrained(ddp / WEIGHTS_NAME)
    ref = ProSplat.from_pretrained(one / WEIGHTS_NAME)
    for (k, a), b in zip(pipe.generator.state_dict().items(), ref.generator.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-5, msg=k)


def test_training_runs_where_the_photo_libraries_are_missing(dataset, tmp_path):
    """A lent GPU machine gets only the wheels scripts/gpu_* carry (no pycolmap, OpenImageIO,
    PyAV): `prosplat train generator` still trains there from a pack (what those scripts
    carry), and the poses step that needs them says what to install."""
    blocked = "import sys; sys.modules.update(OpenImageIO=None, pycolmap=None, av=None); "
    pack = pack_scenes(sorted(dataset.iterdir()), tmp_path / "train_000.npz")
    out = tmp_path / "run"
    args = [
        "train", "generator", "--data", str(pack), "--steps", "1", "--inputs", "2",
        "--targets", "1", "--lpips-weight", "0", "--warmup", "1", "--device", "cpu",
        "--out", str(out),
    ]  # fmt: skip
    code = blocked + f"from prosplat.cli import main; main({args!r})"
    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run(
        [sys.executable, "-c", code], cwd=repo, env=env, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert weights_step(out / WEIGHTS_NAME) == 1
    code = blocked + (
        "from prosplat.poses import estimate_poses, quiet_colmap; quiet_colmap(); "
        "estimate_poses('x', 'y')"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert run.returncode != 0
    assert "needs pycolmap, which this Python lacks: pip install pycolmap" in run.stderr


def _log(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]


def test_devices_follow_the_local_rank_and_one_process_needs_no_group(monkeypatch):
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert pick_device("cuda") == torch.device("cuda", 1)  # not every rank on GPU 0
    assert pick_device("cuda:0") == torch.device("cuda", 0) and pick_device("cpu").type == "cpu"
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    single = setup_distributed("cpu")
    assert (single.rank, single.world_size, single.is_main) == (0, 1, True)
    lin = torch.nn.Linear(1, 1)
    assert single.mean_all({"loss": 2.5}) == {"loss": 2.5} and single.wrap(lin) is lin


@pytest.mark.parametrize("depth_loss", ["inverse", "log"])
def test_init_starts_from_given_weights_and_input_depth_is_supervised(
    dataset, tmp_path, depth_loss
):
    """--init loads weights at step 0 (a fresh optimiser); the input-depth term is the L1 of
    inverse (or log) depth between the generator's input depth maps and Blender's, and training
    on it alone moves the predicted depth towards the truth."""
    torch.manual_seed(0)
    start = ProSplat().save(tmp_path / "start.safetensors")
    fixed = str(dataset.parent / "fixed")
    base = dict(data=fixed, targets=1, inputs=2, lpips_weight=0.0, log_every=1, warmup=1)
    cfg = TrainConfig(
        **base, out=str(tmp_path / "zero"), steps=1, lr=1e-12, init=str(start), save_every=1
    )
    train(cfg, progress=False)
    loaded = ProSplat.from_pretrained(tmp_path / "zero" / WEIGHTS_NAME).generator.state_dict()
    for name, value in ProSplat.from_pretrained(start).generator.state_dict().items():
        torch.testing.assert_close(loaded[name], value, atol=1e-9, rtol=0, msg=name)
    cfg = TrainConfig(
        **base,
        out=str(tmp_path / "depth"),
        steps=30,
        lr=2e-3,
        init=str(start),
        input_depth_weight=10.0,
        depth_loss=depth_loss,
        save_every=30,
    )
    train(cfg, progress=False)
    log = [json.loads(line) for line in (tmp_path / "depth" / "log.jsonl").read_text().splitlines()]
    assert all(r["input_depth"] > 0 for r in log)
    first = sum(r["input_depth"] for r in log[:5]) / 5
    last = sum(r["input_depth"] for r in log[-5:]) / 5
    assert last < 0.8 * first


def test_grow_fine_matching_starts_from_the_init_and_resumes(dataset, tmp_path):
    """--grow-fine-matching: at a learning rate of ~0 the saved network is the init's with a
    fine cost volume added, predicting the same depth; a resume rebuilds the grown network;
    without prosplat --init weights it is refused."""
    torch.manual_seed(0)
    start = ProSplat().save(tmp_path / "start.safetensors")
    base = dict(data=str(dataset.parent / "fixed"), targets=1, inputs=2, lpips_weight=0.0, warmup=1)
    grow = dict(**base, init=str(start), grow_fine_matching=4, lr=1e-12, save_every=1, log_every=1)
    train(TrainConfig(**grow, out=str(tmp_path / "g"), steps=1), progress=False)
    grown = ProSplat.from_pretrained(tmp_path / "g" / WEIGHTS_NAME)
    assert grown.generator.config.fine_matching_channels == 4
    plain = ProSplat.from_pretrained(start)
    scene = SceneDataset(str(dataset.parent / "fixed"), n_inputs=2)[0]
    images, K, w2c = scene["input_images"][None], scene["input_K"][None], scene["input_w2c"][None]
    near, far = scene["near"][None], scene["far"][None]
    with torch.no_grad():
        a = plain.generator.eval()(images, K, w2c, near, far).depths
        b = grown.generator.eval()(images, K, w2c, near, far).depths
    torch.testing.assert_close(b, a, atol=1e-4, rtol=1e-4)
    train(TrainConfig(**grow, out=str(tmp_path / "g"), steps=2), progress=False)  # resume
    log = (tmp_path / "g" / "log.jsonl").read_text().splitlines()
    assert [json.loads(line)["step"] for line in log] == [1, 2]
    with pytest.raises(ValueError, match="grow_fine_matching"):
        TrainConfig(**base, out="x", grow_fine_matching=4)
    # fine-tuning the grown weights again (no --grow): the init's own architecture is built,
    # whatever --config says, and step 0 keeps its weights
    again = dict(**base, init=str(tmp_path / "g" / WEIGHTS_NAME), lr=1e-12, save_every=1)
    train(TrainConfig(**again, out=str(tmp_path / "again"), steps=1), progress=False)
    tuned = ProSplat.from_pretrained(tmp_path / "again" / WEIGHTS_NAME).generator
    assert tuned.config.fine_matching_channels == 4
    for name, value in grown.generator.state_dict().items():
        torch.testing.assert_close(tuned.state_dict()[name], value, atol=1e-9, rtol=0, msg=name)


def test_render_loss_fused_projection_matches_the_torch_projection(dataset):
    """Training renders with the fused C++ projection (faster); the loss and every gradient
    are those of the torch projection, its reference twin, to float32 precision."""
    from prosplat.train.batches import model_inputs
    from prosplat.train.losses import render_loss

    torch.manual_seed(0)
    model = ProSplat().generator.train()
    item = SceneDataset(str(dataset), n_inputs=3, n_targets=2)[0]
    batch = {k: v[None] for k, v in item.items()}
    cfg = TrainConfig(
        data="x", out="x", lpips_weight=0.0, depth_weight=0.1, input_render_weight=0.5
    )
    results = []
    for backend in ("cpu", "cpu-fused"):
        model.zero_grad(set_to_none=True)
        loss, parts = render_loss(model(*model_inputs(batch)), batch, cfg, cpu_backend=backend)
        loss.backward()
        grads = {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}
        results.append((loss.detach(), parts, grads))
    (l0, p0, g0), (l1, p1, g1) = results
    assert p0["input_mse"] > 0 and p0["depth"] > 0
    torch.testing.assert_close(l1, l0, rtol=1e-5, atol=1e-7)
    assert g0.keys() == g1.keys() and len(g0) > 50
    for name in g0:
        torch.testing.assert_close(g1[name], g0[name], rtol=1e-3, atol=1e-6, msg=name)


@pytest.mark.parametrize("fill", [False, True])
def test_render_loss_is_the_mean_of_per_camera_losses(dataset, fill):
    """render_loss renders each group's cameras together (one gsplat call on a GPU); its
    parts are still the per-camera means it documents, recomputed here camera by camera.
    With fill_holes every render is scored as filled by pull-push (the depth term keeps its
    own coverage test)."""
    from prosplat import render
    from prosplat.metrics import LPIPS, ssim
    from prosplat.render.hole_fill import fill_holes
    from prosplat.train.batches import batch_cameras, model_inputs
    from prosplat.train.losses import render_loss

    torch.manual_seed(0)
    model = ProSplat().generator.eval()
    items = [SceneDataset(str(dataset), n_inputs=2, n_targets=2)[i] for i in range(2)]
    batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    cfg = TrainConfig(
        data="x", out="x", lpips_weight=0.3, ssim_weight=0.2, depth_weight=0.1,
        depth_loss="log", input_render_weight=0.5, fill_holes=fill,
    )  # fmt: skip
    lpips_fn = LPIPS()
    holes = 0.0  # the summed squared change the fill makes, to show it had holes to fill
    with torch.no_grad():
        output = model(*model_inputs(batch))
        loss, parts = render_loss(output, batch, cfg, lpips_fn=lpips_fn, cpu_backend="cpu")
        want = dict.fromkeys(("mse", "lpips", "ssim", "depth", "input_mse"), 0.0)
        for b in range(2):
            g = output.gaussians(b)
            for group, weight in (("target", 1.0), ("input", 0.5)):
                images = batch[f"{group}_images"][b]
                h, w = images.shape[-2:]
                cams = batch_cameras(batch[f"{group}_K"][b], batch[f"{group}_w2c"][b], w, h)
                for j, cam in enumerate(cams):
                    out = render(g, cam, backend="cpu")
                    rgb = fill_holes(out.rgb, out.alpha) if fill else out.rgb
                    holes += float(((rgb - out.rgb) ** 2).sum())
                    mse = float(((rgb - images[j]) ** 2).mean())
                    want["mse"] += weight * mse
                    want["input_mse"] += mse if group == "input" else 0.0
                    want["lpips"] += weight * float(lpips_fn(rgb, images[j]))
                    want["ssim"] += weight * (1 - float(ssim(rgb, images[j])))
                    gt_d = batch[f"{group}_depths"][b, j]
                    valid = (gt_d > 0) & (out.alpha > 0.5)
                    want["depth"] += weight * float(
                        (out.depth[valid].clamp_min(1e-3).log() - gt_d[valid].log()).abs().mean()
                    )
    assert want["depth"] > 0 and want["input_mse"] > 0
    assert (holes > 1.0) == fill  # the untrained model's renders leave holes
    for key in ("mse", "lpips", "ssim", "depth"):
        assert parts[key] == pytest.approx(want[key] / 4, rel=1e-4), key
    assert parts["input_mse"] == pytest.approx(want["input_mse"] / 4, rel=1e-4)


def test_input_render_weight_scores_the_input_cameras_from_all_views(dataset, tmp_path):
    """input_render_weight re-renders every input camera from all views' Gaussians: the log's
    input_mse appears, and training on it alone makes the inputs re-render better."""
    torch.manual_seed(0)
    fixed = str(dataset.parent / "fixed")
    base = dict(data=fixed, targets=1, inputs=2, lpips_weight=0.0, log_every=1, warmup=1)
    cfg = TrainConfig(
        **base,
        out=str(tmp_path / "in"),
        steps=25,
        lr=2e-3,
        input_render_weight=1.0,
        save_every=25,
    )
    train(cfg, progress=False)
    log = [json.loads(line) for line in (tmp_path / "in" / "log.jsonl").read_text().splitlines()]
    assert all(r["input_mse"] > 0 for r in log)
    first = sum(r["input_mse"] for r in log[:5]) / 5
    last = sum(r["input_mse"] for r in log[-5:]) / 5
    assert last < 0.8 * first
    # without the weight no input is rendered
    cfg = TrainConfig(**base, out=str(tmp_path / "none"), steps=1, save_every=1)
    train(cfg, progress=False)
    rec = json.loads((tmp_path / "none" / "log.jsonl").read_text().splitlines()[0])
    assert rec["input_mse"] == 0


def test_training_draws_a_size_per_step(dataset, tmp_path):
    """--sizes 32,64 on 32-px data refuses (data is never upsampled); 32 alone trains."""
    base = dict(data=str(dataset), targets=1, inputs=2, lpips_weight=0.0, log_every=1)
    with pytest.raises(ValueError, match="render larger"):
        train(TrainConfig(**base, out=str(tmp_path / "a"), steps=4, sizes="32,64"), progress=False)
    train(TrainConfig(**base, out=str(tmp_path / "b"), steps=2, sizes="32"), progress=False)
    assert (tmp_path / "b" / "checkpoint.safetensors").exists()


def test_training_with_targets_at_twice_the_input_size(tmp_path):
    """--sizes 32 --target-scale 2 on 64-px data: the generator runs at 32 px, its Gaussians
    are scored on 64-px targets, validation does the same, and the weights say 32."""
    from prosplat.core.checkpoints import read_checkpoint

    root = tmp_path / "data64"
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=64, n_views=5)
    cfg = TrainConfig(
        data=str(root),
        val=str(root),
        out=str(tmp_path / "run"),
        targets=1,
        inputs=2,
        lpips_weight=0.0,
        log_every=2,
        val_every=2,
        val_scenes=1,
        steps=2,
        sizes="32",
        target_scale=2,
    )
    path = train(cfg, progress=False)
    rec = json.loads((tmp_path / "run" / "log.jsonl").read_text().splitlines()[-1])
    assert math.isfinite(rec["loss"]) and math.isfinite(rec["val_psnr"])
    assert read_checkpoint(path, "generator")[1]["trained_size"] == "32"


def test_depth_ce_is_the_cross_entropy_with_a_two_hot_of_the_true_inverse_depth():
    """depth_ce: each one-surface cell's target splits between the two candidates that bracket
    its inverse depth (so the target's expectation is that depth), the loss is the mean
    cross-entropy over those cells (its gradient softmax - target), and sky or silhouette cells
    (depths 0 or more than 5 % apart in the cell) do not count."""
    from prosplat.train.losses import depth_ce

    d, near, far = 8, torch.tensor([1.0]), torch.tensor([10.0])
    cand = torch.linspace(1 / 1.0, 1 / 10.0, d)  # the head's candidates, near first
    z = float(1 / (0.75 * cand[3] + 0.25 * cand[4]))  # 1/4 of the way from candidate 3 to 4
    depths = torch.full((1, 2, 8, 8), z)
    depths[0, 1, :4, :4] = 0  # sky in view 1's top-left cell
    depths[0, 1, 4:, :4] = torch.tensor([z, 2 * z]).repeat(4, 2)  # a silhouette cell
    logits = torch.randn(1, 2, d, 2, 2, requires_grad=True)
    loss = depth_ce(logits, depths, near, far)
    target = torch.zeros(d)
    target[3], target[4] = 0.75, 0.25
    logp = torch.log_softmax(logits.detach(), 2)  # [1,2,D,2,2]
    valid = torch.ones(2, 2, 2, dtype=torch.bool)
    valid[1, 0, 0] = valid[1, 1, 0] = False  # [view, row, col]: the sky and silhouette cells
    per_cell = -(target[None, :, None, None] * logp[0]).sum(1)  # [2,2,2]
    torch.testing.assert_close(loss, per_cell[valid].mean())
    loss.backward()
    grad = (logp[0].exp() - target[None, :, None, None]) / valid.sum()  # [2,D,2,2]
    grad = grad * valid[:, None]
    torch.testing.assert_close(logits.grad[0], grad)
    # uniform logits score log D; all-sky depths leave nothing to score
    flat = torch.zeros(1, 2, d, 2, 2)
    torch.testing.assert_close(depth_ce(flat, depths, near, far), torch.log(torch.tensor(8.0)))
    assert float(depth_ce(flat, torch.zeros_like(depths), near, far)) == 0
    with pytest.raises(ValueError, match="multiple"):
        depth_ce(flat, depths[..., :7], near, far)


def test_input_depth_ce_trains_the_depth_head_towards_the_truth(dataset, tmp_path):
    """--input-depth-ce-weight alone: the generator returns its head's logits [B,V,D,h,w] at
    1/4 of the input size, the term is logged, and training on it lowers it."""
    torch.manual_seed(0)
    scene = SceneDataset(str(dataset.parent / "fixed"), n_inputs=2)[0]
    gen = ProSplat().generator.eval()
    with torch.no_grad():
        out = gen(scene["input_images"][None], scene["input_K"][None], scene["input_w2c"][None],
                  scene["near"][None], scene["far"][None])  # fmt: skip
    h, w = scene["input_images"].shape[-2:]
    assert out.depth_logits.shape == (1, 2, gen.config.num_depth_candidates, h // 4, w // 4)
    assert out.detach().depth_logits is not None
    cfg = TrainConfig(data=str(dataset.parent / "fixed"), out=str(tmp_path / "ce"), steps=30,
                      targets=1, inputs=2, lpips_weight=0.0, log_every=1, warmup=1, lr=2e-3,
                      input_depth_ce_weight=1.0, save_every=30)  # fmt: skip
    train(cfg, progress=False)
    log = [json.loads(line) for line in (tmp_path / "ce" / "log.jsonl").read_text().splitlines()]
    first = sum(r["input_depth_ce"] for r in log[:5]) / 5
    last = sum(r["input_depth_ce"] for r in log[-5:]) / 5
    assert all(r["input_depth_ce"] > 0 for r in log) and last < 0.8 * first
    with pytest.raises(ValueError, match="input_depth_ce_weight"):
        TrainConfig(data="x", out="y", input_depth_ce_weight=-1)


def test_log_depth_loss_is_the_same_at_every_scene_scale():
    """--depth-loss log scores the relative error (a scene scaled by s scores the same), while
    the inverse-depth L1 scales with 1/s; both are 0 for the true depth and reject unknown
    kinds at construction."""
    from prosplat.train.losses import depth_error

    gt = torch.tensor([1.0, 2.0, 4.0, 8.0])
    pred = gt * torch.tensor([1.5, 0.5, 1.0, 2.0])
    for s in (0.1, 1.0, 30.0):
        torch.testing.assert_close(
            depth_error(pred * s, gt * s, "log"),
            torch.log(torch.tensor([1.5, 2.0, 1.0, 2.0])).mean(),
        )
    inv = depth_error(pred, gt, "inverse")
    torch.testing.assert_close(depth_error(pred * 10, gt * 10, "inverse"), inv / 10)
    assert float(depth_error(gt, gt, "log")) == 0 and float(depth_error(gt, gt, "inverse")) == 0
    with pytest.raises(ValueError, match="depth_loss"):
        TrainConfig(data="x", out="y", depth_loss="l2")


def test_grow_alexnet_starts_from_the_init(dataset, tmp_path):
    """--grow-alexnet: at a learning rate of ~0 the saved network is the init's with AlexNet
    features added (LPIPS's weights, frozen), predicting the same depth; refused without
    prosplat --init weights."""
    from prosplat.metrics import LPIPS

    torch.manual_seed(0)
    start = ProSplat().save(tmp_path / "start.safetensors")
    base = dict(data=str(dataset.parent / "fixed"), targets=1, inputs=2, lpips_weight=0.0, warmup=1)
    grow = dict(**base, init=str(start), grow_alexnet=2, lr=1e-12, save_every=1, log_every=1)
    train(TrainConfig(**grow, out=str(tmp_path / "g"), steps=1), progress=False)
    grown = ProSplat.from_pretrained(tmp_path / "g" / WEIGHTS_NAME).generator
    assert grown.config.alexnet_layers == 2
    torch.testing.assert_close(grown.monocular.alexnet.conv2_bias, LPIPS().features.conv2.bias)
    scene = SceneDataset(str(dataset.parent / "fixed"), n_inputs=2)[0]
    images, K, w2c = scene["input_images"][None], scene["input_K"][None], scene["input_w2c"][None]
    near, far = scene["near"][None], scene["far"][None]
    with torch.no_grad():
        a = ProSplat.from_pretrained(start).generator.eval()(images, K, w2c, near, far).depths
        b = grown.eval()(images, K, w2c, near, far).depths
    torch.testing.assert_close(b, a, atol=1e-4, rtol=1e-4)
    with pytest.raises(ValueError, match="grow_alexnet"):
        TrainConfig(**base, out="x", grow_alexnet=1)


def test_frame_window_draws_every_other_shape_inside_the_frame():
    """Windows are never the whole frame, their sides are multiples of 32 from 64 up, they fit,
    and every other shape (2:1, 1:2, smaller squares) is drawn; a frame with no other shape is
    refused."""
    import random

    from prosplat.train.batches import frame_window

    rng = random.Random(0)
    shapes = set()
    for _ in range(400):
        top, left, h, w = frame_window(128, 128, rng)
        assert (h, w) != (128, 128) and h % 32 == 0 and w % 32 == 0 and min(h, w) >= 64
        assert 0 <= top <= 128 - h and 0 <= left <= 128 - w
        shapes.add((h, w))
    assert shapes == {(h, w) for h in (64, 96, 128) for w in (64, 96, 128)} - {(128, 128)}
    with pytest.raises(ValueError, match="larger than 64"):
        frame_window(64, 64, rng)
    with pytest.raises(ValueError, match="frame_prob"):
        TrainConfig(data="x", out="y", frame_prob=1.5, sizes="128")
    with pytest.raises(ValueError, match="give sizes"):  # else it would silently do nothing
        TrainConfig(data="x", out="y", frame_prob=0.5)


def test_framed_steps_crop_inputs_and_targets_with_their_cameras(tmp_path):
    """frame_prob=1 at the data's size: every step's inputs, targets and depths take one window
    of another shape, and each cropped pixel's depth unprojects through the shifted intrinsics
    to the same world point as in the full frame; training on framed steps runs."""
    from prosplat.data import SceneDataset
    from prosplat.train.batches import batch_cameras, step_view

    root = tmp_path / "data96"
    write_synthetic_scene(root / "scene", size=96, n_views=4)
    item = SceneDataset(str(root), n_inputs=2, n_targets=1)[0]
    batch = {k: v[None] for k, v in item.items()}
    base = dict(data=str(root), targets=1, inputs=2, lpips_weight=0.0, log_every=1, sizes="96")
    cfg = TrainConfig(**base, out=str(tmp_path / "run"), steps=2, frame_prob=1.0)
    for step in range(6):
        out = step_view(batch, cfg, step)
        h, w = out["input_images"].shape[-2:]
        assert (h, w) != (96, 96) and out["target_depths"].shape[-2:] == (h, w)
        full = batch_cameras(batch["input_K"][0], batch["input_w2c"][0], 96, 96)[0]
        crop = batch_cameras(out["input_K"][0], out["input_w2c"][0], w, h)[0]
        d = out["input_depths"][0, 0]
        row, col = (d > 0).nonzero()[0].tolist()
        uv = torch.tensor([[col + 0.5, row + 0.5]], dtype=torch.float64)
        p = crop.unproject(uv, d[row, col].double()[None])
        uv_full, _ = full.project(p)
        r0, c0 = int(uv_full[0, 1]), int(uv_full[0, 0])  # the same pixel of the full frame
        torch.testing.assert_close(
            batch["input_images"][0, 0, :, r0, c0], out["input_images"][0, 0, :, row, col]
        )
    unframed = TrainConfig(**base, out=str(tmp_path / "none"), steps=1)
    assert step_view(batch, unframed, 0)["input_images"].shape[-2:] == (96, 96)
    train(cfg, progress=False)
    rec = json.loads((tmp_path / "run" / "log.jsonl").read_text().splitlines()[-1])
    assert math.isfinite(rec["loss"]) and rec["step"] == 2
