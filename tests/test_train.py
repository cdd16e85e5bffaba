"""Training the generator end to end on tiny synthetic scene folders (no Blender)."""

from __future__ import annotations

import json

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat
from prosplat.train.generator import TrainConfig, lr_at, train


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=5)
    # exactly 2 inputs and 1 target: every step sees the same batch
    write_synthetic_scene(root.parent / "fixed" / "scene", size=32, n_views=3)
    return root


@pytest.fixture(autouse=True)
def one_thread():
    """Tiny models run faster on one thread here; restore the setting for other tests."""
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


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
    sc_images = torch.rand(2, 3, 32, 32)
    from prosplat.demo_scene import orbit_cameras

    g = pipe.reconstruct(sc_images, orbit_cameras(2, 32, 32), near=0.5, far=10.0)
    assert len(g) == 2 * 32 * 32
    # Resume: the same command with more steps continues from step 3, not from scratch.
    more = TrainConfig(**{**cfg.__dict__, "steps": 5})
    train(more, progress=False)
    steps = [json.loads(line)["step"] for line in (out / "log.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4, 5]
    assert torch.load(out / "state.pt", weights_only=True)["step"] == 5


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
    (out / "train_config.json").write_text("{}")
    with pytest.raises(FileExistsError, match="another run"):
        train(TrainConfig(data=str(dataset), out=str(out), steps=1), progress=False)
