"""The gsplat wrappers' bookkeeping, checked on the CPU through a stand-in ``gsplat`` module.

gsplat needs CUDA, which tests never have. What can still be wrong without it is our side:
stacking cameras into gsplat's batched ``viewmats``/``Ks``, reading its [C,H,W,4] outputs
back into [C,3,H,W] images, compositing the background and zeroing empty depth. The
stand-in follows gsplat 1.5's documented ``rasterization`` contract (RGB accumulated over
black, "ED" the alpha-normalised depth, alphas [C,H,W,1]) with our CPU rasterizer per
camera, so the wrappers must reproduce ``render(..., backend="cpu")`` exactly.
"""

from __future__ import annotations

import sys
import types

import pytest
import torch

from prosplat import Camera, Gaussians, render


def _fake_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
                        *, sh_degree, render_mode, **_):  # fmt: skip
    assert viewmats.dim() == 3 and viewmats.shape[1:] == (4, 4)
    assert Ks.shape == (viewmats.shape[0], 3, 3) and render_mode == "RGB+ED"
    assert viewmats.dtype == torch.float32 and Ks.dtype == torch.float32
    g = Gaussians(means, quats, scales, opacities, colors)
    assert g.sh_degree == sh_degree
    rgbd, alphas, radii = [], [], []
    for viewmat, K in zip(viewmats, Ks):
        out = render(g, Camera(K.double(), viewmat.double(), width, height), backend="cpu")
        rgbd.append(torch.cat([out.rgb.permute(1, 2, 0), out.depth[..., None]], dim=-1))
        alphas.append(out.alpha[..., None])
        radii.append(out.visible[:, None].expand(-1, 2).int())
    return torch.stack(rgbd), torch.stack(alphas), {"radii": torch.stack(radii)}


@pytest.fixture
def fake_gsplat(monkeypatch):
    module = types.ModuleType("gsplat")
    module.rasterization = _fake_rasterization
    monkeypatch.setitem(sys.modules, "gsplat", module)


def _scene(seed: int = 0) -> tuple[Gaussians, list[Camera]]:
    gen = torch.Generator().manual_seed(seed)
    n = 200
    g = Gaussians(
        means=torch.randn(n, 3, generator=gen),
        quats=torch.randn(n, 4, generator=gen),
        scales=torch.rand(n, 3, generator=gen) * 0.3 + 0.02,
        opacities=torch.rand(n, generator=gen),
        sh=torch.randn(n, 4, 3, generator=gen) * 0.4,
    )
    eyes = [(0.3, 0.2, -4.0), (2.5, -0.4, -3.0), (-3.5, 0.6, -1.0)]
    cams = [Camera.look_at(e, (0, 0, 0), (0, -1, 0), 30.0, 36, 28) for e in eyes]
    return g, cams


def test_render_gsplat_views_matches_the_cpu_rasterizer(fake_gsplat):
    from prosplat.render.gsplat_backend import render_gsplat, render_gsplat_views

    g, cams = _scene()
    bg = torch.tensor([0.2, 0.5, 0.9])
    rgb, alpha, depth = render_gsplat_views(g, cams, bg)
    assert rgb.shape == (3, 3, 28, 36) and alpha.shape == depth.shape == (3, 28, 36)
    for j, cam in enumerate(cams):
        ref = render(g, cam, background=bg, backend="cpu")
        one = render_gsplat(g, cam, bg)
        assert (ref.alpha < 0.5).any(), "the background must show through somewhere"
        for got in (rgb[j], one.rgb):
            torch.testing.assert_close(got, ref.rgb, atol=1e-5, rtol=0)
        torch.testing.assert_close(alpha[j], ref.alpha, atol=1e-5, rtol=0)
        torch.testing.assert_close(depth[j], ref.depth, atol=1e-4, rtol=0)
        assert torch.equal(one.visible, ref.visible)


def test_render_gsplat_views_refuses_mixed_sizes_and_float64(fake_gsplat):
    from prosplat.render.gsplat_backend import render_gsplat_views

    g, cams = _scene()
    small = Camera.look_at((0, 0, -4.0), (0, 0, 0), (0, -1, 0), 30.0, 20, 20)
    with pytest.raises(ValueError, match="of one size"):
        render_gsplat_views(g, [*cams, small], torch.zeros(3))
    with pytest.raises(ValueError, match="float32"):
        render_gsplat_views(g.to(dtype=torch.float64), cams, torch.zeros(3))
