"""The weight average (``--ema``): its recurrence, and what a training run saves and resumes
with it, on tiny synthetic scenes (no Blender)."""

from __future__ import annotations

import json

import pytest
import torch
from synthetic_scenes import write_synthetic_scene
from torch import nn

from prosplat import ProSplat
from prosplat.core.checkpoints import read_checkpoint
from prosplat.train.ema import WeightAverage
from prosplat.train.generator import train
from prosplat.train.generator_config import TrainConfig


class _Net(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.lin = nn.Linear(3, 2)
        self.register_buffer("count", torch.zeros((), dtype=torch.long))


def test_weight_average_follows_its_warmed_up_recurrence():
    torch.manual_seed(0)
    net = _Net()
    avg = WeightAverage(net, decay=0.9)
    expected = net.lin.weight.detach().clone()
    for n in range(30):
        with torch.no_grad():
            net.lin.weight.copy_(torch.randn(2, 3))
            net.count += 1
        d = min(0.9, (1 + n) / (10 + n))
        expected = d * expected + (1 - d) * net.lin.weight.detach()
        avg.update(net)
    torch.testing.assert_close(avg.state_dict()["lin.weight"], expected)
    assert int(avg.state_dict()["count"]) == 30  # integer buffers are copied, not averaged
    assert avg.updates == 30 and avg.current_decay() == pytest.approx(31 / 40)  # still warming
    # a restored average continues as the original would
    again = WeightAverage(_Net(), decay=0.9)
    again.load_state_dict(avg.state_dict(), updates=avg.updates)
    for a in (avg, again):
        a.update(net)
    for k, v in avg.state_dict().items():
        torch.testing.assert_close(again.state_dict()[k], v)
    with pytest.raises(KeyError, match="missing"):
        again.load_state_dict({"lin.weight": torch.zeros(2, 3)}, updates=1)
    for bad in (0.0, 1.0, -0.5):
        with pytest.raises(ValueError, match="decay"):
            WeightAverage(net, decay=bad)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=5)
    return root


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one thread is faster


def _base(dataset) -> dict:
    return dict(
        data=str(dataset),
        steps=4,
        inputs=2,
        targets=1,
        lpips_weight=0.0,
        log_every=1,
        save_every=10,
        warmup=1,
        lr=3e-3,
    )


def _raw(run) -> dict[str, torch.Tensor]:
    return torch.load(run.parent / "state.pt", weights_only=True)["raw_weights"]


def _close(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-4, atol=1e-5)


def test_ema_saves_the_average_and_never_changes_the_training(dataset, tmp_path):
    """The raw weights of a run with --ema are those of the same run without it, also when the
    average is switched off at a resume; the saved weights are the average, which loads as
    any generator."""
    base = _base(dataset)
    plain = train(TrainConfig(**base, out=str(tmp_path / "plain")), progress=False)
    ema = train(TrainConfig(**base, out=str(tmp_path / "ema"), ema=0.5), progress=False)
    mixed = tmp_path / "mixed"
    train(TrainConfig(**base, out=str(mixed), ema=0.5, stop_at=2), progress=False)
    mixed_end = train(TrainConfig(**base, out=str(mixed)), progress=False)

    plain_w = read_checkpoint(plain, "generator")[0]
    _close(_raw(ema), plain_w)
    _close(read_checkpoint(mixed_end, "generator")[0], plain_w)

    avg_w, meta = read_checkpoint(ema, "generator")
    assert json.loads(meta["ema"]) == {"decay": 0.5, "updates": 4}
    moved = max(float((avg_w[k] - plain_w[k]).abs().max()) for k in plain_w)
    assert moved > 1e-4, "the saved weights are the raw ones, not their average"
    ProSplat.from_pretrained(ema)  # the averaged file is a generator like any other
    assert "ema" not in read_checkpoint(mixed_end, "generator")[1]
    # the switch is recorded: the config it ran with before is kept beside the new one
    before = json.loads((mixed / "train_config.before_2.json").read_text())
    assert before["ema"] == 0.5
    assert json.loads((mixed / "train_config.json").read_text())["ema"] == 0.0


def test_ema_resumes_as_one_uninterrupted_run(dataset, tmp_path):
    base = {**_base(dataset), "ema": 0.5}
    whole = train(TrainConfig(**base, out=str(tmp_path / "whole")), progress=False)
    train(TrainConfig(**base, out=str(tmp_path / "parts"), stop_at=2), progress=False)
    parts = train(TrainConfig(**base, out=str(tmp_path / "parts")), progress=False)
    _close(read_checkpoint(parts, "generator")[0], read_checkpoint(whole, "generator")[0])
    _close(_raw(parts), _raw(whole))
    assert not list((tmp_path / "parts").glob("train_config.before_*"))  # nothing changed


def test_ema_turned_on_at_a_resume_starts_from_the_weights_there(dataset, tmp_path):
    base = _base(dataset)
    run = tmp_path / "late"
    train(TrainConfig(**base, out=str(run), stop_at=2), progress=False)
    end = train(TrainConfig(**base, out=str(run), ema=0.5), progress=False)
    assert json.loads(read_checkpoint(end, "generator")[1]["ema"])["updates"] == 2
    plain = train(TrainConfig(**base, out=str(tmp_path / "plain")), progress=False)
    _close(_raw(end), read_checkpoint(plain, "generator")[0])
    assert json.loads((run / "train_config.before_2.json").read_text())["ema"] == 0.0


def test_a_config_written_before_a_setting_existed_is_not_a_change(dataset, tmp_path):
    base = _base(dataset)
    run = tmp_path / "old"
    train(TrainConfig(**base, out=str(run), stop_at=2), progress=False)
    cfg = json.loads((run / "train_config.json").read_text())
    del cfg["ema"]  # as a run started before --ema wrote it
    (run / "train_config.json").write_text(json.dumps(cfg))
    train(TrainConfig(**base, out=str(run)), progress=False)
    assert not list(run.glob("train_config.before_*"))


def test_ema_is_refused_outside_its_range():
    with pytest.raises(ValueError, match="ema"):
        TrainConfig(data="d", out="o", ema=1.0)
    with pytest.raises(ValueError, match="ema"):
        TrainConfig(data="d", out="o", ema=-0.1)
