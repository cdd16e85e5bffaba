"""Stage-2 training augmentation (crops and flips with the fundamental matrix carried along)
and the alpha input, against epipolar geometry computed from the cameras themselves."""

from __future__ import annotations

import pytest
import torch

from prosplat.core.camera import Camera
from prosplat.improve.config import ImproveConfig
from prosplat.improve.epipolar import fundamental_matrix
from prosplat.improve.model import ImproveModel
from prosplat.train.augment import (
    augment_samples,
    shift_disagreement,
    shifted_pairs,
    subpixel_translate,
)


def _pair() -> tuple[Camera, Camera, torch.Tensor]:
    a = Camera.look_at([0.0, 0.0, -3.0], [0, 0, 0], [0, -1, 0], 60.0, 64, 64)
    b = Camera.look_at([1.5, 0.3, -2.5], [0, 0, 0], [0, -1, 0], 60.0, 64, 64)
    g = torch.Generator().manual_seed(0)
    points = (torch.rand(200, 3, generator=g, dtype=torch.float64) - 0.5) * 1.5
    return a, b, points


def _h(uv: torch.Tensor) -> torch.Tensor:
    return torch.cat([uv, torch.ones_like(uv[:, :1])], 1)


def test_cropped_and_flipped_fundamental_matrix_keeps_points_on_their_epipolar_lines():
    a, b, points = _pair()
    F = fundamental_matrix(a, b).double()  # x_b^T F x_a = 0
    uv_a, _ = a.project(points)
    uv_b, _ = b.project(points)
    assert (_h(uv_b) * (F @ _h(uv_a).T).T).sum(1).abs().max() < 1e-6
    for seed in range(6):
        rng = torch.Generator().manual_seed(seed)
        # a marker image per camera tells where each crop window started and whether it flipped
        ramp = torch.arange(64, dtype=torch.float32)
        mark = torch.stack(
            [ramp[None].expand(64, 64), ramp[:, None].expand(64, 64), torch.zeros(64, 64)]
        )
        r, ref, f, t, al = augment_samples(
            mark[None],
            mark[None] + 0.0,
            F[None],
            mark[None],
            torch.ones(1, 1, 64, 64),
            48,
            True,
            rng,
        )
        assert r.shape == (1, 3, 48, 48) and al.shape == (1, 1, 48, 48)
        assert torch.equal(r, t)  # render and ground truth share their window

        # recover each image's map x' = T x from its marker: column index and flip
        def mapping(x):
            cols, rows = x[0, 0, 0], x[0, 1, :, 0]
            ox, oy = float(cols.min()), float(rows[0])
            flipped = bool(cols[0] > cols[-1])
            return ox, oy, flipped

        def apply(uv, m):
            ox, oy, flipped = m
            u, v = uv[:, 0] - ox, uv[:, 1] - oy
            return torch.stack([48 - u if flipped else u, v], 1)

        m_r, m_ref = mapping(r), mapping(ref)
        res = (_h(apply(uv_b, m_ref)) * (f[0].double() @ _h(apply(uv_a, m_r)).T).T).sum(1)
        assert res.abs().max() < 1e-6, seed


def test_alpha_input_starts_as_identity_and_then_matters():
    torch.manual_seed(0)
    cfg = ImproveConfig(alpha_input=True)
    model = ImproveModel(cfg).eval()
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    F = torch.zeros(1, 3, 3, dtype=torch.float64)
    holes = torch.ones(1, 1, 32, 32)
    holes[..., 8:16, 8:16] = 0
    with torch.no_grad():
        assert torch.equal(model(x, ref, F, holes), model(x, ref, F))  # zero-initialised
        torch.nn.init.normal_(model.alpha_in.weight)
        torch.nn.init.normal_(model.vae.decoder.conv_out.weight, std=0.1)
        assert not torch.allclose(model(x, ref, F, holes), model(x, ref, F))


def test_warp_input_starts_as_identity_loads_old_weights_and_then_matters(tmp_path):
    """A warp-input model is the same function as its weights without it (zero start, so
    load_improver(warp_input=True) upgrades a shipped model exactly), until warp_in learns."""
    from prosplat.improve.io import load_improver, save_improver

    torch.manual_seed(0)
    old = ImproveModel(ImproveConfig(alpha_input=True)).eval()
    with torch.no_grad():
        torch.nn.init.normal_(old.vae.decoder.conv_out.weight, std=0.1)  # a trained-like model
    path = save_improver(old, tmp_path / "old.safetensors")
    model = load_improver(path, warp_input=True)
    assert model.config.warp_input and model.config.alpha_input
    x, ref = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    F = torch.zeros(1, 3, 3, dtype=torch.float64)
    warp = torch.cat([torch.rand(1, 3, 32, 32), torch.ones(1, 1, 32, 32)], 1)
    with torch.no_grad():
        assert torch.equal(model(x, ref, F, None, warp), old(x, ref, F))
        assert torch.equal(model(x, ref, F), old(x, ref, F))  # no warp given = no warp
        torch.nn.init.normal_(model.warp_in.weight)
        assert not torch.allclose(model(x, ref, F, None, warp), model(x, ref, F))
    assert (
        model.num_parameters()["warp_in"]
        == 4 * 9 * model.vae.config.block_out_channels[0] + (model.vae.config.block_out_channels[0])
    )


def test_replicate_padding_cannot_stamp_a_pattern_on_a_flat_view():
    """With zero padding the network knows where it is in the image, so a flat grey render
    comes back with structure (v1's fixed pattern); with replicate padding (every padded
    convolution, and the VAE's stride-2 convolutions made symmetric) it cannot."""
    torch.manual_seed(0)
    flat = torch.full((1, 3, 32, 32), 0.5)
    F = torch.zeros(1, 3, 3, dtype=torch.float64)

    def spread(model):
        with torch.no_grad():
            torch.nn.init.normal_(model.vae.decoder.conv_out.weight, std=0.1)
            change = model.eval()(flat, flat, F) - flat
        return float((change - change.mean(dim=(2, 3), keepdim=True)).abs().max())

    zeros = ImproveModel(ImproveConfig())
    assert spread(zeros) > 1e-3
    state = zeros.state_dict()
    rep = ImproveModel(ImproveConfig(padding="replicate"))
    rep.load_state_dict(state)  # same parameters, same names
    assert spread(rep) < 1e-5
    zeros.set_padding("replicate")  # in place, as fine-tuning from zero-padded weights does
    assert zeros.config.padding == "replicate" and spread(zeros) < 1e-5
    with pytest.raises(ValueError, match="zero to replicate"):
        zeros.set_padding("zeros")


def test_shifted_pairs_are_one_window_moved_with_their_epipolar_geometry():
    """The twin of a window is the same picture moved by (dy, dx), flipped alike, with the same
    reference window, and its fundamental matrix still holds for the cameras' points."""
    a, b, points = _pair()
    F = fundamental_matrix(a, b).double()
    uv_a, _ = a.project(points)
    uv_b, _ = b.project(points)
    ramp = torch.arange(64, dtype=torch.float32)
    mark = torch.stack(
        [ramp[None].expand(64, 64), ramp[:, None].expand(64, 64), torch.zeros(64, 64)]
    )
    batch = mark[None].expand(4, -1, -1, -1)
    rng = torch.Generator().manual_seed(0)
    (r, ref, f, t, al), shifts, flipped = shifted_pairs(
        batch, batch + 0.0, F[None].expand(4, 3, 3), batch, torch.ones(4, 1, 64, 64), 48, True, rng
    )
    assert r.shape == (8, 3, 48, 48) and al.shape == (8, 1, 48, 48) and torch.equal(r, t)
    assert shifts.shape == (4, 2) and bool((shifts.sum(1) > 0).all()) and int(shifts.max()) <= 7
    assert flipped.any() and not flipped.all()  # this seed draws both
    for i in range(4):
        dy, dx = (int(v) for v in shifts[i])
        first, twin = r[i], r[4 + i]
        if flipped[i]:
            first, twin = first.flip(-1), twin.flip(-1)
        assert torch.equal(first[:, dy:, dx:], twin[:, : 48 - dy, : 48 - dx])
        assert torch.equal(ref[i], ref[4 + i])
        for k in (i, 4 + i):
            cols = r[k, 0, 0]
            ox, oy, fl = float(cols.min()), float(r[k, 1, 0, 0]), bool(cols[0] > cols[-1])
            rc = ref[k, 0, 0]
            rox, roy, rfl = float(rc.min()), float(ref[k, 1, 0, 0]), bool(rc[0] > rc[-1])

            def apply(uv, ox, oy, fl):
                u, v = uv[:, 0] - ox, uv[:, 1] - oy
                return torch.stack([48 - u if fl else u, v], 1)

            res = _h(apply(uv_b, rox, roy, rfl)) * (f[k].double() @ _h(apply(uv_a, ox, oy, fl)).T).T
            assert res.sum(1).abs().max() < 1e-6


def test_shift_disagreement_is_zero_for_a_convolution_and_sees_an_8px_pattern():
    """A convolution moves with its input: no disagreement inside the margin. Adding a
    pattern tied to 8-px cells (what v9 stamps) does not, whatever the shift."""
    g = torch.Generator().manual_seed(1)
    images = torch.rand(6, 3, 64, 64, generator=g)
    (r, *_), shifts, flipped = shifted_pairs(
        images, images, torch.zeros(6, 3, 3), images, None, 48, True, g
    )
    conv = torch.nn.Conv2d(3, 3, 5, padding=2)
    with torch.no_grad():
        smooth = conv(r)
        assert float(shift_disagreement(smooth, shifts, flipped)) < 1e-12
        yy, xx = torch.meshgrid(torch.arange(48), torch.arange(48), indexing="ij")
        cells = 0.05 * torch.cos(2 * torch.pi * yy / 8) * torch.cos(2 * torch.pi * xx / 8)
        assert float(shift_disagreement(smooth + cells, shifts, flipped)) > 1e-4
    with pytest.raises(ValueError, match="larger than the samples"):
        shifted_pairs(images, images, torch.zeros(6, 3, 3), images, None, 60, False, g)


def test_subpixel_translate_is_exact_on_a_ramp_and_whole_pixels():
    """Pixel p of the result is the input at p + delta: exact for a linear ramp (bilinear
    interpolation reproduces it) away from the repeated edge, a plain shift for whole pixels,
    and the identity for no motion."""
    h, w = 12, 16
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64),
                            torch.arange(w, dtype=torch.float64), indexing="ij")  # fmt: skip
    ramp = (0.3 * ys + 0.7 * xs)[None, None].expand(2, 3, h, w)  # [2,3,H,W]
    delta = torch.tensor([[0.25, -0.4], [-0.5, 0.1]], dtype=torch.float64)
    out = subpixel_translate(ramp, delta)
    want = ramp + (0.3 * delta[:, 0] + 0.7 * delta[:, 1])[:, None, None, None]
    assert torch.allclose(out[..., 1:-1, 1:-1], want[..., 1:-1, 1:-1], atol=1e-9)
    img = torch.rand(1, 3, h, w, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    moved = subpixel_translate(img, torch.tensor([[1.0, 2.0]], dtype=torch.float64))
    assert torch.allclose(moved[..., : h - 1, : w - 2], img[..., 1:, 2:], atol=1e-9)
    assert torch.allclose(subpixel_translate(img, torch.zeros(1, 2, dtype=torch.float64)), img)
