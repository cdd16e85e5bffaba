"""Camera effects on the generator's training inputs (prosplat.train.camera_effects): each effect
against its reference behaviour, the draw's determinism, and the training step that applies
them to the inputs only."""

from __future__ import annotations

import json
import math

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import cli
from prosplat.train.camera_effects import (
    CameraEffects,
    ViewEffects,
    apply_camera_effects,
    apply_view_effects,
    draw_view_effects,
    gaussian_blur,
    input_camera_effects,
    jpeg_round_trip,
    vignette_map,
)
from prosplat.train.generator_config import TrainConfig


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    """Tiny tensors: one thread (see tests/conftest.py)."""


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _only(name: str) -> CameraEffects:
    """Defaults with only ``name`` drawn, and always on for a view given effects."""
    return CameraEffects(enabled=(name,), each=1.0)


def _smooth(h: int = 64, w: int = 64) -> torch.Tensor:
    """[3,H,W] gentle colour gradients in [0.2, 0.8]."""
    ys = torch.linspace(0, 1, h)[:, None].expand(h, w)
    xs = torch.linspace(0, 1, w)[None].expand(h, w)
    return 0.2 + 0.6 * torch.stack([xs, ys, 0.5 * (xs + ys)])


def test_probability_zero_returns_the_input_unchanged():
    x = torch.rand(2, 3, 3, 32, 32)
    out = apply_camera_effects(x, _gen(0), 0.0, CameraEffects())
    assert torch.equal(out, x)
    g = _gen(0)
    views = draw_view_effects(4, g, 0.0, CameraEffects())
    assert views == [None] * 4


def test_effects_follow_the_seed_and_keep_shape_dtype_device_and_range():
    x = torch.rand(2, 4, 3, 32, 48, dtype=torch.float64)
    a = apply_camera_effects(x, _gen(3), 1.0, CameraEffects())
    b = apply_camera_effects(x, _gen(3), 1.0, CameraEffects())
    c = apply_camera_effects(x, _gen(4), 1.0, CameraEffects())
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert a.shape == x.shape and a.dtype == x.dtype and a.device == x.device
    assert a.min() >= 0 and a.max() <= 1
    # the batch is view by view what apply_view_effects gives (its JPEGs made together)
    views = draw_view_effects(8, _gen(3), 1.0, CameraEffects())
    one_by_one = [apply_view_effects(im, v) for im, v in zip(x.flatten(0, 1), views)]
    assert torch.equal(a.flatten(0, 1), torch.stack(one_by_one))
    v = apply_camera_effects(x[0], _gen(3), 1.0, CameraEffects())  # [V,3,H,W] too
    assert v.shape == x[0].shape
    # every view given effects, each effect on for about half of them: different mixes
    views = draw_view_effects(400, _gen(5), 1.0, CameraEffects())
    assert all(v is not None for v in views)
    share = {
        "exposure": sum(v.gain != 1 for v in views) / 400,
        "jpeg": sum(v.jpeg is not None for v in views) / 400,
        "noise": sum(v.noise is not None for v in views) / 400,
        "blur": sum(v.blur > 0 for v in views) / 400,
    }
    assert all(0.4 < s < 0.6 for s in share.values()), share
    assert len({(v.gain != 1, v.jpeg is None, v.noise is None, v.blur > 0) for v in views}) == 16
    assert all(0.5**0.5 <= v.gain <= 2**0.5 for v in views)
    assert all(60 <= v.jpeg <= 95 for v in views if v.jpeg is not None)
    half = draw_view_effects(2000, _gen(6), 0.5, CameraEffects())
    assert 0.45 < sum(v is not None for v in half) / 2000 < 0.55


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_effects_stay_on_the_gpu():
    x = torch.rand(1, 4, 3, 64, 64, device="cuda")
    out = apply_camera_effects(x, _gen(0), 1.0, CameraEffects(each=1.0))
    assert out.device == x.device and out.dtype == x.dtype and out.min() >= 0


def test_exposure_scales_mid_grey_by_the_drawn_gain():
    x = torch.full((4, 3, 16, 16), 0.5)
    (view, *_) = draw_view_effects(4, _gen(1), 1.0, _only("exposure"))
    out = apply_camera_effects(x, _gen(1), 1.0, _only("exposure"))
    assert view.gain != 1 and view.jpeg is None and view.noise is None
    torch.testing.assert_close(out[0], torch.full_like(x[0], 0.5 * view.gain))
    gains = {round(v.gain, 6) for v in draw_view_effects(4, _gen(1), 1.0, _only("exposure"))}
    assert len(gains) == 4  # each view its own gain
    wb = draw_view_effects(1, _gen(2), 1.0, _only("white_balance"))[0]
    out = apply_view_effects(x[0], wb)
    torch.testing.assert_close(out[:, 0, 0], 0.5 * torch.tensor(wb.white_balance))
    assert all(0.94 <= g <= 1.06 for g in wb.white_balance)


def test_vignetting_darkens_the_corners_and_leaves_the_centre():
    x = torch.full((3, 65, 65), 0.5)
    out = apply_view_effects(x, ViewEffects(vignetting=0.3))
    assert out[0, 32, 32] == pytest.approx(0.5, abs=1e-6)  # the centre pixel
    corners = out[:, [0, 0, -1, -1], [0, -1, 0, -1]]
    assert torch.all(corners < 0.5 * 0.75) and torch.all(corners > 0.5 * 0.65)
    m = vignette_map(64, 96, 0.3)
    assert m[32, 48] == pytest.approx(1.0, abs=1e-3) and m.min() >= 0.7 - 1e-6
    assert torch.all(m[32, 48:].diff() <= 0)  # falls off monotonically towards the edge


def test_blur_removes_a_checkerboards_high_frequencies():
    ys, xs = torch.meshgrid(torch.arange(128), torch.arange(128), indexing="ij")
    board = ((ys + xs) % 2).float().expand(3, 128, 128) * 0.8 + 0.1  # [3,128,128]

    def high(img: torch.Tensor) -> float:
        f = torch.fft.fft2(img - img.mean())
        freq = torch.fft.fftfreq(128).abs()
        mask = (freq[:, None] > 0.25) | (freq[None] > 0.25)
        return float((f.abs() ** 2)[:, mask].sum())

    # sigma 0.8 px: a 1-px checker's amplitude x exp(-2 pi^2 sigma^2 / 4) = 0.04
    blurred = apply_view_effects(board, ViewEffects(blur=0.8))
    assert high(blurred) < 0.01 * high(board)
    # blur keeps the light
    assert float(blurred.mean()) == pytest.approx(float(board.mean()), abs=1e-3)
    # the sigma is given at 128 px: at 256 px an impulse spreads twice as far
    for size, sigma in ((128, 1.0), (256, 2.0)):
        delta = torch.zeros(3, size, size)
        delta[:, size // 2, size // 2] = 1
        spread = apply_view_effects(delta, ViewEffects(blur=1.0))[0, size // 2]
        d = torch.arange(size) - size // 2
        var = float((spread * d**2).sum() / spread.sum())
        assert math.sqrt(var) == pytest.approx(sigma, rel=0.05)
    assert torch.equal(gaussian_blur(board, 0.0), board)


def test_noise_std_follows_the_poisson_gaussian_model():
    a, b = 3e-3, 5e-3
    for x in (0.1, 0.3, 0.6):
        flat = torch.full((3, 128, 128), x)
        out = apply_view_effects(flat, ViewEffects(noise=(a, b), noise_seed=7))
        assert float(out.std()) == pytest.approx(math.sqrt(a * x + b * b), rel=0.03)
        assert float(out.mean()) == pytest.approx(x, abs=2e-3)
    # the drawn (a, b), within their ranges, on a drawn view
    effects = _only("noise")
    view = draw_view_effects(1, _gen(9), 1.0, effects)[0]
    lo, hi = effects.shot_noise
    assert view.noise is not None and lo <= view.noise[0] <= hi
    flat = torch.full((1, 3, 128, 128), 0.5)
    out = apply_camera_effects(flat, _gen(9), 1.0, effects)
    a, b = view.noise
    assert float(out.std()) == pytest.approx(math.sqrt(a * 0.5 + b * b), rel=0.03)


def test_jpeg_keeps_a_smooth_image_and_changes_a_noisy_one():
    smooth = _smooth().double()
    back = jpeg_round_trip(smooth, 60)
    assert back.dtype == torch.float64 and back.shape == smooth.shape
    err = (back - smooth).abs()
    assert float(err.mean()) < 2 / 255 and float(err.max()) < 8 / 255
    noisy = torch.rand(3, 64, 64, generator=_gen(0))
    assert float((jpeg_round_trip(noisy, 60) - noisy).abs().mean()) > 0.05
    view = draw_view_effects(1, _gen(0), 1.0, _only("jpeg"))[0]
    assert view.jpeg is not None
    out = apply_view_effects(noisy, view)
    assert torch.equal(out, jpeg_round_trip(noisy, view.jpeg))


def test_bad_settings_fail_clearly():
    with pytest.raises(ValueError, match="camera_effects"):
        TrainConfig(data="x", out="y", camera_effects=1.5)
    with pytest.raises(ValueError, match="camera_effects"):
        TrainConfig(data="x", out="y", camera_effects=-0.1)
    with pytest.raises(ValueError, match="unknown camera effects"):
        CameraEffects(enabled=("rain",))
    with pytest.raises(ValueError, match="prob"):
        apply_camera_effects(torch.rand(1, 3, 8, 8), _gen(0), 2.0, CameraEffects())


def _batch(b: int = 2, v: int = 3) -> dict[str, torch.Tensor]:
    g = _gen(0)
    return {
        "input_images": torch.rand(b, v, 3, 32, 32, generator=g),
        "target_images": torch.rand(b, 2, 3, 32, 32, generator=g),
        "input_K": torch.eye(3).expand(b, v, 3, 3),
    }


def test_the_step_changes_the_inputs_only_seeded_by_seed_and_step():
    batch = _batch()
    cfg = TrainConfig(data="x", out="y", camera_effects=1.0)
    out = input_camera_effects(batch, cfg, step=3)
    assert out["target_images"] is batch["target_images"]  # the clean truth, untouched
    assert out["input_K"] is batch["input_K"]
    assert not torch.equal(out["input_images"], batch["input_images"])
    assert torch.equal(out["input_images"], input_camera_effects(batch, cfg, 3)["input_images"])
    assert not torch.equal(out["input_images"], input_camera_effects(batch, cfg, 4)["input_images"])
    other = TrainConfig(data="x", out="y", camera_effects=1.0, seed=1)
    assert not torch.equal(
        out["input_images"], input_camera_effects(batch, other, 3)["input_images"]
    )
    off = TrainConfig(data="x", out="y")
    assert input_camera_effects(batch, off, 3) is batch  # 0: off, exactly today's batch
    # two ranks with one scene each get the effects of one process with both scenes
    halves = [
        input_camera_effects({k: t[r : r + 1] for k, t in batch.items()}, cfg, 3, r, 2)
        for r in range(2)
    ]
    whole = torch.cat([h["input_images"] for h in halves])
    torch.testing.assert_close(whole, out["input_images"], rtol=0, atol=0)


def test_training_with_camera_effects_runs_and_records_the_setting(tmp_path):
    """A tiny `prosplat train generator --camera-effects 0.5 --roll-prob 1` run (every view
    turned: prosplat.train.view_rotation); the settings round-trip through
    train_config.json."""
    root = tmp_path / "data"
    for k in range(2):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=5)
    out = tmp_path / "run"
    args = [
        "train", "generator", "--data", str(root), "--out", str(out), "--steps", "2",
        "--inputs", "2", "--targets", "1", "--lpips-weight", "0", "--log-every", "1",
        "--warmup", "1", "--device", "cpu", "--camera-effects", "0.5", "--roll-prob", "1",
    ]  # fmt: skip
    with pytest.raises(SystemExit) as done:
        cli.main(args)
    assert done.value.code == 0
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2] and all(math.isfinite(r["loss"]) for r in log)
    saved = json.loads((out / "train_config.json").read_text())
    assert saved["camera_effects"] == 0.5
    assert TrainConfig(**saved).camera_effects == 0.5
    assert saved["roll_prob"] == 1.0
