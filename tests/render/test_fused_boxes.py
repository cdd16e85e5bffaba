"""The pixel boxes and drawn flags the fused projection kernel computes against the torch
twin's (prosplat.render.projection.pixel_boxes, wider_than), exactly; its no-grad path (the
Gaussians' own dtype, no float64 copies) against its autograd path; and depth_order (one C++
radix sort) against torch's stable argsort."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from prosplat import Camera, Gaussians
from prosplat.eval.demo_scene import orbit_cameras
from prosplat.render.fused import depth_order, project_gaussians_fused
from prosplat.render.projection import MIN_ALPHA, project_gaussians, wider_than


def edge_gaussians(n: int, seed: int, cam: Camera, dtype: torch.dtype) -> Gaussians:
    """Gaussians whose means project onto the image border (and beyond it), some behind the
    camera or nearer than the near plane, from 1e-4 to 10x the scene in size, with opacities
    at, under and just over 1/255."""
    gen = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    z = torch.empty(n, dtype=f64).uniform_(-2.0, 8.0, generator=gen)
    z[:20] = torch.linspace(-0.02, 0.03, 20, dtype=f64)  # around the 0.01 near plane
    edges = torch.tensor([0.0, cam.width, 0.0, cam.height], dtype=f64)
    u = edges[torch.randint(0, 2, (n,), generator=gen)] + torch.randn(n, generator=gen, dtype=f64)
    v = edges[2 + torch.randint(0, 2, (n,), generator=gen)] + 3 * torch.randn(
        n, generator=gen, dtype=f64
    )
    inside = torch.rand(n, generator=gen) < 0.3
    u[inside] = torch.rand(int(inside.sum()), generator=gen, dtype=f64) * cam.width
    cam_pts = torch.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], dim=-1)
    R, t = cam.R.to(f64), cam.t.to(f64)
    means = (cam_pts - t) @ R  # world = Rᵀ (p - t)
    quats = torch.randn(n, 4, generator=gen, dtype=f64)
    scales = torch.empty(n, 3, dtype=f64).uniform_(-9, 1.0, generator=gen).exp()
    opacities = torch.rand(n, generator=gen, dtype=f64)
    opacities[:30] = torch.tensor([MIN_ALPHA, MIN_ALPHA * (1 - 1e-7), MIN_ALPHA * (1 + 1e-7)] * 10)
    sh = 0.3 * torch.randn(n, 1, 3, generator=gen, dtype=f64)
    return Gaussians(means, quats, scales, opacities, sh).to(dtype=dtype)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    size=st.tuples(st.integers(1, 70), st.integers(1, 70)),
    dtype=st.sampled_from([torch.float32, torch.float64]),
    max_radius=st.sampled_from([None, 0.01, 0.05, 0.3]),
)
def test_kernel_boxes_are_the_torch_boxes(seed, size, dtype, max_radius):
    cam = orbit_cameras(3, *size)[seed % 3]
    g = edge_gaussians(400, seed, cam, dtype)
    fast = project_gaussians_fused(g, cam, max_radius)
    slow = project_gaussians(g, cam)
    valid = slow.valid
    if max_radius is not None:
        valid = valid & ~wider_than(slow, cam, max_radius)
    assert torch.equal(fast.boxes, slow.boxes)
    assert torch.equal(fast.valid, valid)
    assert fast.boxes.dtype == torch.int32 and fast.means2d.dtype == dtype


def test_the_cases_are_there_and_the_no_grad_path_is_the_autograd_path():
    """The edge cases the property test draws do occur (boxes clipped at every border, drawn
    and undrawn Gaussians behind, at and in front of the near plane, faint ones left out),
    and the no-grad kernel (float32 in, float32 out) gives the autograd path's values bitwise:
    it rounds the same float64 results once."""
    cam = orbit_cameras(3, 40, 30)[1]
    g = edge_gaussians(3000, 0, cam, torch.float32)
    fast = project_gaussians_fused(g, cam)
    b, ok = fast.boxes[fast.valid], fast.valid
    assert (b[:, 0] == 0).any() and (b[:, 1] == cam.width - 1).any()
    assert (b[:, 2] == 0).any() and (b[:, 3] == cam.height - 1).any()
    assert ok.any() and not ok.all() and not ok[fast.depths < 0.01].any()
    assert not ok[g.opacities < MIN_ALPHA].any()
    assert torch.equal(
        fast.boxes[~ok], torch.tensor([[1, 0, 1, 0]], dtype=torch.int32).expand(int((~ok).sum()), 4)
    )
    leaves = Gaussians(*[t.clone().requires_grad_(True) for t in g.tensors().values()])
    graded = project_gaussians_fused(leaves, cam, 0.05)
    plain = project_gaussians_fused(g, cam, 0.05)
    assert graded.means2d.requires_grad
    for name in ("means2d", "conics", "depths", "boxes", "valid"):
        assert torch.equal(getattr(graded, name).detach(), getattr(plain, name)), name
    assert not torch.equal(plain.valid, fast.valid)  # the cap left some out


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(0, 3000),
    dtype=st.sampled_from([torch.float32, torch.float64]),
    levels=st.sampled_from([3, 1000, 0]),
)
def test_depth_order_is_the_stable_argsort(seed, n, dtype, levels):
    """Ties (few distinct depths) keep index order; depths near the plane and far away."""
    gen = torch.Generator().manual_seed(seed)
    depths = torch.rand(n, generator=gen, dtype=torch.float64).mul(1e4).add(0.01)
    if levels:
        depths = (depths * levels / 1e4).floor() + 0.01
    depths = depths.to(dtype)
    depths[torch.rand(n, generator=gen) < 0.2] *= -1  # behind: never drawn
    valid = (torch.rand(n, generator=gen) < 0.8) & (depths >= 0.01)
    idx = torch.nonzero(valid).squeeze(1)
    want = idx[torch.argsort(depths[idx], stable=True)]
    assert torch.equal(depth_order(depths, valid), want)
