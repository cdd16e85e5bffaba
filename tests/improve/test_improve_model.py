"""The stage-2 improvement model: one-step update, identity at init, gradients, a training step,
checkpoints, the SD-Turbo-format loading path with LoRA, and ProSplat.render."""

from __future__ import annotations

import math

import pytest
import torch
from improve_configs import SMALL

from prosplat import ProSplat
from prosplat.core.camera import Camera
from prosplat.eval.demo_scene import demo_scene, orbit_cameras
from prosplat.improve.config import TINY, ImproveConfig
from prosplat.improve.epipolar import fundamental_matrix
from prosplat.improve.io import load_improver, save_improver
from prosplat.improve.model import ImproveModel, build_unet, build_vae
from prosplat.pipeline.enhance import pad_to_multiple


def _perturb(model: torch.nn.Module, std: float = 0.05) -> None:
    """Make the zero-initialised parts nonzero so every parameter influences the output."""
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in model.parameters():
            if p.abs().max() == 0 or p.numel() < 2 or p.std() == 0:
                p.copy_(torch.randn(p.shape, generator=g) * std)


def _pair(size: int = 32) -> tuple[Camera, Camera]:
    a, b = orbit_cameras(2, size, size, arc_deg=40.0)
    return a, b


def test_untrained_model_is_identity() -> None:
    torch.manual_seed(0)
    model = ImproveModel(SMALL).eval()
    x = torch.rand(2, 3, 32, 32)
    ref = torch.rand(2, 3, 32, 32)
    a, b = _pair()
    f = torch.stack([fundamental_matrix(a, b)] * 2).float()
    with torch.no_grad():
        assert torch.equal(model(x, ref, f), x)


def test_one_step_matches_scheduler() -> None:
    model = ImproveModel(SMALL.with_(timestep=199))
    z, eps = torch.randn(1, 4, 8, 8), torch.randn(1, 4, 8, 8)
    expected = model.scheduler.step(eps, 199, z).pred_original_sample
    torch.testing.assert_close(model.one_step(z, eps), expected, rtol=1e-5, atol=1e-5)
    abar = model.scheduler.alphas_cumprod[199]
    torch.testing.assert_close(
        model.one_step(z, eps), (z - (1 - abar).sqrt() * eps) / abar.sqrt(), rtol=1e-5, atol=1e-5
    )


@pytest.mark.parametrize(
    "row", [dict(denoise=False, reference=False), dict(), dict(vae_skip=False)]
)
def test_gradients_reach_every_parameter(row: dict) -> None:
    torch.manual_seed(0)
    model = ImproveModel(SMALL.with_(**row))
    _perturb(model)
    a, b = _pair()
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    out = model(x, ref, fundamental_matrix(a, b).float()[None])
    assert out.shape == x.shape and torch.isfinite(out).all()
    (out - torch.rand_like(out)).square().mean().backward()
    missing = [
        n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0
    ]
    assert missing == []


def test_one_training_step_lowers_the_loss() -> None:
    torch.manual_seed(0)
    model = ImproveModel(SMALL)
    x = torch.rand(2, 3, 32, 32)
    gt = (x * 0.8 + 0.1).clamp(0, 1)  # a colour change the model must learn
    ref = gt.flip(0)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)

    def loss() -> torch.Tensor:
        return (model(x, ref, None) - gt).square().mean()

    before = loss()
    before.backward()
    opt.step()
    with torch.no_grad():
        after = loss()
    assert after < before


def test_vanishing_fundamental_gives_finite_output() -> None:
    torch.manual_seed(0)
    model = ImproveModel(SMALL)
    _perturb(model)
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    a = _pair()[0]
    zero = fundamental_matrix(a, a).float()[None]  # coincident cameras: F = 0
    assert zero.abs().max() == 0
    with torch.no_grad():
        out_zero = model(x, ref, zero)
        out_none = model(x, ref, None)
    assert torch.isfinite(out_zero).all()
    torch.testing.assert_close(out_zero, out_none)


def test_bf16_autocast_is_finite_and_close() -> None:
    torch.manual_seed(0)
    model = ImproveModel(SMALL).eval()
    _perturb(model, 0.02)
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        full = model(x, ref, None)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            half = model(x, ref, None).float()
    assert torch.isfinite(half).all()
    assert (half - full).abs().mean() < 0.02


def test_errors_name_the_fix() -> None:
    model = ImproveModel(SMALL)
    with pytest.raises(ValueError, match="multiples of 8"):
        model(torch.rand(1, 3, 30, 32), torch.rand(1, 3, 30, 32))
    with pytest.raises(ValueError, match="reference="):
        model(torch.rand(1, 3, 32, 32))
    with pytest.raises(ValueError, match="groups"):
        ImproveConfig(vae_channels=(30, 32))
    with pytest.raises(ValueError, match="timestep"):
        ImproveConfig(timestep=1000)


def test_checkpoint_round_trip(tmp_path) -> None:
    torch.manual_seed(0)
    model = ImproveModel(SMALL)
    _perturb(model)
    path = save_improver(model, tmp_path / "m.safetensors", command="test")
    with pytest.raises(FileExistsError):
        save_improver(model, path)
    loaded = load_improver(path)
    assert loaded.config == SMALL
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        assert torch.equal(model.eval()(x, ref, None), loaded(x, ref, None))
    with pytest.raises(FileNotFoundError):
        load_improver(tmp_path / "missing.safetensors")


def test_tiny_preset_size() -> None:
    n = sum(ImproveModel(TINY).num_parameters().values())
    assert 1e6 < n < 5e6


def test_sd_turbo_format_with_lora(tmp_path) -> None:
    """A tiny random model saved in diffusers' SD-Turbo layout loads, gets LoRA adapters on
    pix2pix-turbo's modules, and trains only adapters + new modules."""
    pytest.importorskip("peft")
    from safetensors.torch import save_file

    from prosplat.improve.pretrained import from_diffusers

    torch.manual_seed(0)
    sd = SMALL.with_(unet_cross_attention=(True, True, False), scaling_factor=0.18215)
    build_vae(sd).save_pretrained(tmp_path / "vae")
    build_unet(sd).save_pretrained(tmp_path / "unet")
    emb = torch.randn(1, 77, sd.cross_attention_dim)
    save_file({"prompt_embedding": emb}, str(tmp_path / "empty_prompt.safetensors"))

    model = from_diffusers(tmp_path, timestep=999)
    assert model.config.timestep == 999 and model.config.residual is False
    assert model.config.scaling_factor == pytest.approx(0.18215)
    torch.testing.assert_close(model.prompt_embedding, emb)
    trainable = {n for n, p in model.named_parameters() if p.requires_grad}
    assert any("lora" in n and n.startswith("unet.") for n in trainable)
    assert any("lora" in n and n.startswith("vae.") for n in trainable)
    base = [n for n in trainable if n.startswith(("unet.", "vae.")) and "lora" not in n]
    assert base == []
    assert any(n.startswith("skip_convs.") for n in trainable)
    assert any(n.startswith("dwea.") for n in trainable)

    before = {n: p.detach().clone() for n, p in model.named_parameters()}
    opt = torch.optim.SGD([p for p in model.parameters() if p.requires_grad], lr=1e-2)
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    out = model(x, ref, None)
    assert torch.isfinite(out).all()
    (out - x).square().mean().backward()
    opt.step()
    changed = {n for n, p in model.named_parameters() if not torch.equal(p, before[n])}
    assert changed and changed <= trainable


def test_sd_turbo_missing_folder_is_clear(tmp_path) -> None:
    from prosplat.improve.pretrained import from_diffusers

    with pytest.raises(FileNotFoundError, match="diffusers-format"):
        from_diffusers(tmp_path)


def test_pipeline_render_pads_and_enhances() -> None:
    """ProSplat.render at a size that is not a multiple of the stride: padded, cropped back,
    reference chosen by MORI, timings reported; an untrained improver returns the raw render."""
    torch.manual_seed(0)
    gaussians, inputs = demo_scene(24, n_inputs=2)
    images = torch.rand(2, 3, 24, 24)
    target = orbit_cameras(5, 40, 30, arc_deg=40.0)[2]
    model = ProSplat(improver=ImproveModel(SMALL))
    view = model.render(gaussians, target, images, inputs)
    assert view.image.shape == (3, 30, 40) and view.raw.shape == (3, 30, 40)
    assert view.reference in (0, 1)
    assert set(view.timings) == {"render_ms", "mori_ms", "enhance_ms"}
    torch.testing.assert_close(view.image, view.raw)  # identity at init
    raw = model.render(gaussians, target, enhance=False)
    assert raw.reference is None and raw.image is raw.raw
    with pytest.raises(ValueError, match="improvement model"):
        ProSplat().render(gaussians, target, images, inputs)


def test_pad_to_multiple_replicates_edges() -> None:
    x = torch.arange(12.0).reshape(1, 1, 3, 4).expand(1, 3, 3, 4)
    y = pad_to_multiple(x, 8)
    assert y.shape == (1, 3, 8, 8)
    assert torch.equal(y[..., :3, :4], x)
    assert torch.equal(y[..., 7, 7], x[..., 2, 3])
    assert math.isclose(float(y[0, 0, 0, 7]), 3.0)


def test_epipolar_switch_makes_dwea_plain_attention() -> None:
    """``epipolar=False`` (the "plain" ablation row) ignores F: the output is DWEA with no
    fundamental matrix, and differs from the epipolar-weighted one for a real camera pair."""
    torch.manual_seed(0)
    model = ImproveModel(SMALL).eval()
    _perturb(model)
    with torch.no_grad():  # a DWEA strong enough for its weighting to show at the output
        for p in [*model.dwea.parameters(), *model.injection.parameters()]:
            p.normal_(0.0, 1.0)
    a, b = _pair()
    f = fundamental_matrix(a, b).float()[None]
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        weighted, plain = model(x, ref, f), model(x, ref, None)
        model.config = model.config.with_(epipolar=False)
        off = model(x, ref, f)
    torch.testing.assert_close(off, plain, rtol=0, atol=1e-6)
    assert float((weighted - plain).abs().max()) > 1e-5  # 100x the float noise


def test_load_improver_can_drop_the_reference(tmp_path) -> None:
    """The "none" and "warp" ablation rows start from a reference model's weights without
    DWEA: every other weight loads unchanged, and the model runs without a reference."""
    torch.manual_seed(0)
    full = ImproveModel(SMALL).eval()
    _perturb(full)
    path = save_improver(full, tmp_path / "full.safetensors")
    bare = load_improver(path, drop_reference=True, warp_input=True)
    assert not bare.config.reference and bare.config.warp_input and bare.dwea is None
    kept = bare.state_dict()
    for name, value in full.state_dict().items():
        if name.startswith(("dwea.", "injection.")):
            assert name not in kept
        else:
            assert torch.equal(kept[name], value), name
    with torch.no_grad():
        out = bare(torch.rand(1, 3, 32, 32))
    assert out.shape == (1, 3, 32, 32) and torch.isfinite(out).all()


def test_fill_input_enhances_the_filled_render(tmp_path) -> None:
    """``fill_input``: the model sees (and adds its residual to) the render with its holes
    filled from its own colours; the same weights loaded with ``fill_input=True`` give
    exactly the plain model's output on the filled render, and without alpha the render is
    taken as covered (no fill). An untrained fill model returns the filled render."""
    from prosplat.render.hole_fill import fill_holes

    torch.manual_seed(0)
    plain = ImproveModel(SMALL.with_(alpha_input=True)).eval()
    x = torch.rand(2, 3, 32, 32)
    alpha = torch.ones(2, 1, 32, 32)
    alpha[:, :, :, 20:] = 0  # a hole on the right: black in the render
    x = x * alpha
    ref = torch.rand(2, 3, 32, 32)
    a, b = _pair()
    f = torch.stack([fundamental_matrix(a, b)] * 2).float()
    filled = fill_holes(x, alpha)
    with torch.no_grad():
        assert torch.allclose(ImproveModel(SMALL.with_(fill_input=True)).eval()(x, ref, f, alpha),
                              filled, atol=1e-6)  # fmt: skip
        _perturb(plain)
        path = save_improver(plain, tmp_path / "plain.safetensors")
        fill = load_improver(path, fill_input=True)
        assert fill.config.fill_input and not plain.config.fill_input
        want = plain(filled, ref, f, alpha)
        assert torch.allclose(fill(x, ref, f, alpha), want, atol=1e-6)
        assert not torch.allclose(plain(x, ref, f, alpha), want, atol=1e-3)  # it matters
        assert torch.allclose(fill(x, ref, f), plain(x, ref, f), atol=1e-6)  # no alpha: no fill
    again = load_improver(save_improver(fill, tmp_path / "fill.safetensors"))
    assert again.config.fill_input  # the weights say how to use them
