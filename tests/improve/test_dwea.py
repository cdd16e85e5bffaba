"""DWEA: identity at init, attention concentrated on epipolar lines, plain attention fallback."""

from __future__ import annotations

import pytest
import torch

from prosplat import Camera
from prosplat.improve.dwea import DWEA, DepthwiseSeparableConv, DWEAInjection, epipolar_modulation
from prosplat.improve.epipolar import fundamental_matrix

STRIDE = 8.0
UP = (0.0, -1.0, 0.0)


def _pair() -> tuple[Camera, Camera]:
    """A converging pair with a vertical offset, so the epipolar lines are slanted."""
    target = Camera.look_at((0.5, -0.2, -4.0), (0.0, 0.0, 0.0), UP, 110.0, 128, 96)
    ref = Camera.look_at((-2.0, 0.8, -3.4), (0.1, 0.1, 0.0), UP, 100.0, 128, 96)
    return target, ref


def _features(gen: torch.Generator, b: int = 1, c: int = 8, h: int = 12, w: int = 16):
    target = torch.randn(b, c, h, w, generator=gen)
    ref = torch.randn(b, c, h, w, generator=gen)
    return target, ref


def _plain_weights(m: DWEA, target: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """Independent plain attention: sigmoid scores normalised per row, [B, heads, Nt, Nr]."""
    B, C, h, w = target.shape
    d = C // m.heads
    q = m.to_q(m.norm_q(target)).reshape(B, m.heads, d, -1).transpose(2, 3)
    refn = m.norm_kv(ref)
    k = m.to_k(refn).reshape(B, m.heads, d, -1).transpose(2, 3)
    s = torch.sigmoid(q @ k.transpose(2, 3) / d**0.5)
    return s / s.sum(-1, keepdim=True)


def _brute_distances(target: Camera, ref: Camera, t_hw, r_hw) -> torch.Tensor:
    """[Nt, Nr] pixel distances to lines through two reprojected points of each target ray."""

    def centres(hw):
        r, c = torch.meshgrid(torch.arange(hw[0]), torch.arange(hw[1]), indexing="ij")
        return torch.stack([c, r], -1).reshape(-1, 2).double() * STRIDE + STRIDE / 2

    uv_t, uv_r = centres(t_hw), centres(r_hw)
    ones = torch.ones(len(uv_t), dtype=torch.float64)
    p1 = ref.project(target.unproject(uv_t, 0.5 * ones))[0]
    p2 = ref.project(target.unproject(uv_t, 9.0 * ones))[0]

    def homog(x):
        return torch.cat([x, torch.ones_like(x[:, :1])], -1)

    lines = torch.linalg.cross(homog(p1), homog(p2))
    lines = lines / lines[:, :2].norm(dim=-1, keepdim=True)
    return (lines @ homog(uv_r).T).abs()


def test_untrained_dwea_is_the_identity() -> None:
    gen = torch.Generator().manual_seed(0)
    target, ref = _features(gen, b=2)
    t_cam, r_cam = _pair()
    F = torch.stack([fundamental_matrix(t_cam, r_cam)] * 2)
    m = DWEA(8, heads=2)
    out = m(target, ref, F, STRIDE)
    assert torch.equal(out, target)
    assert torch.equal(m(target, ref, None, STRIDE), target)


@pytest.mark.parametrize("rectified", [False, True])
def test_flat_scores_concentrate_on_the_epipolar_line(rectified: bool) -> None:
    t_cam, r_cam = _pair()
    if rectified:  # a pure sideways shift: horizontal lines along the feature rows
        r_cam = Camera.look_at((1.5, -0.2, -4.0), (1.0, 0.0, 0.0), UP, 110.0, 128, 96)
    F = fundamental_matrix(t_cam, r_cam)[None]
    gen = torch.Generator().manual_seed(1)
    target, ref = _features(gen)
    m = DWEA(8)
    with torch.no_grad():  # zero Q and K projections: every plain score is 0
        for conv in (m.to_q, m.to_k):
            conv.weight.zero_()
            conv.bias.zero_()
    _, weights = m(target, ref, F, STRIDE, return_weights=True)
    assert weights.shape == (1, 1, 192, 192)
    torch.testing.assert_close(weights.sum(-1), torch.ones(1, 1, 192))

    d = _brute_distances(t_cam, r_cam, (12, 16), (12, 16)) / STRIDE  # in feature cells
    # Rows whose line runs through the reference map (≥ 4 cells within half a cell of it); a
    # line that only clips a corner has so few on-line cells that its tail weighs more.
    crosses = (d < 0.5).sum(-1) >= 4
    assert crosses.sum() > 100
    near_mass = (weights[0, 0] * (d <= 1.5)).sum(-1)[crosses]
    assert near_mass.min() >= 0.9 and near_mass.mean() >= 0.94
    # plain attention (no F) would spread the same row uniformly
    _, plain = m(target, ref, None, STRIDE, return_weights=True)
    assert (plain[0, 0] * (d <= 1.5)).sum(-1)[crosses].max() < 0.5


def test_vanishing_or_missing_F_falls_back_to_plain_attention() -> None:
    gen = torch.Generator().manual_seed(2)
    target, ref = _features(gen, b=2)
    m = DWEA(8, heads=2)
    with torch.no_grad():
        m.to_out.weight.normal_(generator=gen)
    t_cam, r_cam = _pair()
    eye = t_cam.center
    rotated = Camera.look_at(eye, eye + torch.tensor([0.3, 0.1, 1.0]), UP, 90.0, 128, 96)
    F_rot = fundamental_matrix(t_cam, rotated)
    F_same = fundamental_matrix(t_cam, t_cam)
    assert not F_rot.any() and not F_same.any()

    expected = _plain_weights(m, target, ref)
    out_none, w_none = m(target, ref, None, STRIDE, return_weights=True)
    torch.testing.assert_close(w_none, expected)
    assert torch.isfinite(out_none).all() and not torch.equal(out_none, target)
    for F in (torch.stack([F_rot, F_same]), torch.zeros(2, 3, 3)):
        out, w = m(target, ref, F, STRIDE, return_weights=True)
        torch.testing.assert_close(w, w_none)
        torch.testing.assert_close(out, out_none)

    # A batch mixing a real pair with a vanishing one: only the real one is modulated.
    mixed = torch.stack([fundamental_matrix(t_cam, r_cam), F_rot])
    out, w = m(target, ref, mixed, STRIDE, return_weights=True)
    torch.testing.assert_close(w[1], w_none[1])
    assert (w[0] - w_none[0]).abs().max() > 1e-3 and torch.isfinite(out).all()


def test_modulation_is_min_max_normalised_and_flat_where_unconstrained() -> None:
    t_cam, r_cam = _pair()
    F = torch.stack([fundamental_matrix(t_cam, r_cam), torch.zeros(3, 3, dtype=torch.float64)])
    mod = epipolar_modulation(F, (12, 16), (6, 8), STRIDE)
    assert mod.shape == (2, 192, 48) and mod.dtype == torch.float32
    torch.testing.assert_close(mod[0].amax(-1), torch.ones(192))
    torch.testing.assert_close(mod[0].amin(-1), torch.zeros(192))
    assert torch.equal(mod[1], torch.ones(192, 48))


def test_gradients_reach_every_parameter() -> None:
    gen = torch.Generator().manual_seed(3)
    target, ref = _features(gen)
    target.requires_grad_(True)
    ref.requires_grad_(True)
    m = DWEA(8, heads=2)
    with torch.no_grad():
        m.to_out.weight.normal_(generator=gen)
    F = fundamental_matrix(*_pair())[None]
    out = m(target, ref, F, STRIDE)
    (out * torch.randn(out.shape, generator=gen)).sum().backward()
    for name, p in m.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    assert ref.grad.abs().sum() > 0 and target.grad.abs().sum() > 0


def test_dwea_guards_and_errors() -> None:
    with pytest.raises(ValueError, match="multiple of heads"):
        DWEA(6, heads=4)
    m = DWEA(4)
    big, small = torch.zeros(1, 4, 128, 128), torch.zeros(1, 4, 64, 64)
    with pytest.raises(ValueError, match="bottleneck"):  # 2^28 attention elements
        m(big, big, None, STRIDE)
    with pytest.raises(ValueError, match=r"F must be \[B=1, 3, 3\]"):
        m(small[:, :, :4, :4], small[:, :, :4, :4], torch.zeros(2, 3, 3), STRIDE)
    with pytest.raises(ValueError, match="channels"):
        m(torch.zeros(1, 8, 4, 4), torch.zeros(1, 8, 4, 4), None, STRIDE)


def test_depthwise_separable_conv_shapes() -> None:
    conv = DepthwiseSeparableConv(6, 10)
    assert conv(torch.randn(2, 6, 5, 7)).shape == (2, 10, 5, 7)
    assert conv.depthwise.groups == 6 and conv.depthwise.kernel_size == (3, 3)
    assert conv.pointwise.kernel_size == (1, 1)


def test_injection_shapes_zero_init_and_training_signal() -> None:
    gen = torch.Generator().manual_seed(4)
    inj = DWEAInjection(16, out_channels=(32, 16, 8), scales=(1, 2, 4))
    fused = torch.randn(2, 16, 4, 5, generator=gen)
    outs = inj(fused)
    assert [tuple(o.shape) for o in outs] == [(2, 32, 4, 5), (2, 16, 8, 10), (2, 8, 16, 20)]
    assert all(torch.equal(o, torch.zeros_like(o)) for o in outs)
    sized = inj(fused, sizes=[(4, 5), (7, 9), (13, 17)])
    assert [tuple(o.shape[2:]) for o in sized] == [(4, 5), (7, 9), (13, 17)]

    # Zero-initialised but trainable: the loss reaches the pointwise convs.
    sum(o.sum() for o in inj(fused)).backward()
    for branch in inj.branches:
        assert branch.pointwise.weight.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="equal length"):
        DWEAInjection(16, out_channels=(32, 16), scales=(1, 2, 4))
