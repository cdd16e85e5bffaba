"""The fused C++ projection (prosplat.render.fused) against its twin, the torch projection:
float64, forward and backward, on Gaussians in front of, behind and beside the camera, needles
and blobs, with view-dependent colour."""

from __future__ import annotations

import pytest
import torch

from prosplat import Camera, Gaussians, render
from prosplat.eval.demo_scene import orbit_cameras
from prosplat.render.fused import project_gaussians_fused
from prosplat.render.projection import project_gaussians


def random_gaussians(n: int, seed: int) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    means = (torch.rand(n, 3, generator=gen, dtype=f64) - 0.5) * torch.tensor([8.0, 8.0, 12.0])
    quats = torch.randn(n, 4, generator=gen, dtype=f64)
    scales = torch.empty(n, 3, dtype=f64).uniform_(-9, 0.5, generator=gen).exp()
    opacities = torch.rand(n, generator=gen, dtype=f64)
    sh = 0.3 * torch.randn(n, 4, 3, generator=gen, dtype=f64)
    return Gaussians(means, quats, scales, opacities, sh)


def project_and_grads(fn, g: Gaussians, cam: Camera):
    leaves = [t.detach().clone().requires_grad_(True) for t in g.tensors().values()]
    p = fn(Gaussians(*leaves), cam)
    gen = torch.Generator().manual_seed(1)
    loss = sum(
        (x * torch.randn(x.shape, generator=gen, dtype=x.dtype)).sum()
        for x in (p.means2d, p.conics, p.depths, p.colors, p.opacities)
    )
    loss.backward()
    return p, [t.grad for t in leaves]


@pytest.mark.parametrize("seed, size", [(0, (40, 32)), (1, (17, 23))])
def test_fused_projection_matches_the_torch_twin_forward_and_backward(seed, size):
    g = random_gaussians(3000, seed)
    cam = orbit_cameras(3, *size)[1]
    slow, g_slow = project_and_grads(project_gaussians, g, cam)
    fast, g_fast = project_and_grads(project_gaussians_fused, g, cam)
    z = slow.depths.detach()
    assert (z < 0).any() and (z > 0.01).any()  # behind and in front of the camera
    assert slow.valid.any() and not slow.valid.all()
    assert torch.equal(fast.boxes, slow.boxes) and torch.equal(fast.valid, slow.valid)
    for name in ("means2d", "conics", "depths", "colors"):
        a, b = getattr(fast, name).detach(), getattr(slow, name).detach()
        assert torch.allclose(a, b, rtol=1e-12, atol=1e-12), name
    for name, a, b in zip(g.tensors(), g_fast, g_slow):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-10 * float(b.abs().max())), name


def test_cpu_fused_backend_renders_the_same_image():
    g = random_gaussians(2000, 2).to(dtype=torch.float32)
    cam = orbit_cameras(3, 48, 40)[1]
    a, b = render(g, cam), render(g, cam, backend="cpu-fused")
    assert torch.allclose(a.rgb, b.rgb, atol=1e-6) and torch.equal(a.visible, b.visible)
    with pytest.raises(ValueError, match="cpu-fused"):
        render(g, cam, backend="fused")
