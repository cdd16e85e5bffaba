"""``prosplat train generator --init X.pth``: fine-tuning a DepthSplat checkpoint's Gaussian
regressor and head on synthetic scenes, everything else frozen; the result is a
released-layout .pth that ``ProSplat.from_pretrained(generator=...)`` loads and renders, and
a run resumes like any generator run. The checkpoint is the random-weights small model in the
released format (tests/pipeline/test_depthsplat_pipeline.py), at 32 px."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import ProSplat, cli  # noqa: F401
from prosplat.eval.demo_scene import orbit_cameras
from prosplat.generator.depthsplat import random_encoder, save_released_format
from prosplat.generator.depthsplat.config import SMALL
from prosplat.generator.depthsplat.load import CONFIG_KEY, PREFIX
from prosplat.train.common import weights_step
from prosplat.train.depthsplat_heads import TRAINABLE, finetuned_path, load_for_tuning
from prosplat.train.generator import train
from prosplat.train.generator_config import TrainConfig

NAME = "depthsplat-gs-small-re10k-256x256-view2-cfeab6b1.pth"


@pytest.fixture(scope="module")
def released_file(tmp_path_factory) -> Path:
    return save_released_format(random_encoder(SMALL, 7), tmp_path_factory.mktemp("ds") / NAME)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("data")
    for k in range(2):  # 2 inputs and 1 target each
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=3)
    return root


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one thread is faster


def _encoder_sd(path: Path) -> dict[str, torch.Tensor]:
    sd = torch.load(path, map_location="cpu", weights_only=True)["state_dict"]
    return {k[len(PREFIX) :]: v for k, v in sd.items()}


def _cli(args: list[str]) -> None:
    with pytest.raises(SystemExit) as e:
        cli.main(args)
    assert e.value.code == 0


def test_fine_tune_trains_only_the_heads_writes_a_loadable_pth_and_resumes(
    released_file, dataset, tmp_path, capsys
) -> None:
    out = tmp_path / "run"
    args = ["train", "generator", "--data", str(dataset), "--out", str(out), "--init",
            str(released_file), "--inputs", "2", "--targets", "1", "--lpips-weight", "0",
            "--warmup", "1", "--log-every", "1", "--save-every", "1", "--device", "cpu",
            "--val", str(dataset), "--val-every", "2", "--val-scenes", "1"]  # fmt: skip
    _cli([*args, "--steps", "2"])
    result = finetuned_path(out, released_file)
    assert result.name == NAME.removesuffix(".pth") + "-prosplat-ft.pth"
    assert f"checkpoint: {result.resolve()}" in capsys.readouterr().out

    before, after = _encoder_sd(released_file), _encoder_sd(result)
    assert before.keys() == after.keys()
    heads = {k for k in before if k.startswith(TRAINABLE)}
    assert heads and all(k.split(".")[0] in TRAINABLE for k in heads)
    for k in before.keys() - heads:  # frozen: bit for bit
        assert torch.equal(before[k], after[k]), k
    assert all(not torch.equal(before[k], after[k]) for k in heads)
    stored = torch.load(result, weights_only=True)
    assert stored[CONFIG_KEY]["gaussian_scale_max"] == SMALL.gaussian_scale_max
    assert stored["prosplat_meta"] == {"init": NAME, "step": 2, "trained": ",".join(TRAINABLE)}

    # the resumable pair holds the heads only
    assert weights_step(out / "checkpoint.safetensors") == 2
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2] and all(r["loss"] > 0 for r in log)
    assert log[-1]["val_psnr"] > 0  # validation runs the tuned model in eval mode

    model = ProSplat.from_pretrained(generator=result, improve=False)
    cams = orbit_cameras(2, 32, 32)
    g = model.reconstruct(torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0)),
                          cams, near=0.5, far=10.0, budget="all").gaussians  # fmt: skip
    assert len(g) == 2 * 32 * 32
    view = model.render(g, orbit_cameras(3, 32, 32)[1], enhance=False)
    assert torch.isfinite(view.image).all() and float(view.image.std()) > 0

    # resume: the same command with more steps continues at step 3, the frozen rest unchanged
    _cli([*args, "--steps", "3"])
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3]
    again = _encoder_sd(result)
    assert all(torch.equal(before[k], again[k]) for k in before.keys() - heads)
    assert any(not torch.equal(after[k], again[k]) for k in heads)
    assert torch.load(result, weights_only=True)["prosplat_meta"]["step"] == 3


def test_frozen_modules_stay_in_eval_mode_and_without_gradients(released_file) -> None:
    model = load_for_tuning(released_file).train()
    enc = model.encoder
    assert model.training and enc.gaussian_head.training and enc.gaussian_regressor.training
    assert not enc.depth_predictor.training and not enc.feature_upsampler.training
    assert not any(m.training for m in enc.depth_predictor.modules())
    names = {n.split(".")[0] for n, p in enc.named_parameters() if p.requires_grad}
    assert names == set(TRAINABLE)
    trained = sum(p.numel() for p in model.trainable_parameters())
    assert trained == 133_087  # README, "DepthSplat weights"
    assert trained < 0.01 * sum(p.numel() for p in enc.parameters())
    model.eval()
    assert not enc.gaussian_head.training


def test_fine_tune_refuses_input_depth_supervision_and_a_foreign_run(
    released_file, dataset, tmp_path
) -> None:
    cfg = TrainConfig(data=str(dataset), out=str(tmp_path / "a"), init=str(released_file),
                      steps=1, targets=1, lpips_weight=0.0, input_depth_weight=0.1, device="cpu")  # fmt: skip
    with pytest.raises(ValueError, match="frozen"):
        train(cfg, progress=False)
    # a prosplat generator run's folder is not resumed as a DepthSplat fine-tune
    plain = TrainConfig(data=str(dataset), out=str(tmp_path / "b"), steps=1, targets=1,
                        lpips_weight=0.0, warmup=1, device="cpu")  # fmt: skip
    train(plain, progress=False)
    ft = TrainConfig(**{**plain.__dict__, "init": str(released_file), "steps": 2})
    with pytest.raises(ValueError, match="new --out"):
        train(ft, progress=False)


def test_curation_renders_a_depthsplat_generator(released_file, dataset, tmp_path) -> None:
    """The improvement model trains on DepthSplat's renders: ``train curate --generator X.pth``
    reconstructs with the DepthSplat checkpoint and stores its renders of the targets."""
    from prosplat.train.curate import load_curated

    out = tmp_path / "curated.safetensors"
    _cli(["train", "curate", "--data", str(dataset), "--out", str(out), "--views", "2",
          "--generator", str(released_file)])  # fmt: skip
    data = load_curated(out)
    assert data["render"].shape == (2, 3, 32, 32)  # 2 scenes x 1 target
    assert float(data["alpha"].float().mean()) > 0.05  # the Gaussians cover the view
    assert not torch.equal(data["render"], data["target"])
