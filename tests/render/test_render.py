"""The fast CPU rasterizer against its brute-force twin, analytic values, and hard cases."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera, Gaussians, render
from prosplat.core.gaussians import rgb_to_sh0
from prosplat.render.reference import render_reference

F64 = torch.float64


def random_gaussians(
    n: int, sh_degree: int, seed: int, dtype=F64, spread: float = 1.0
) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    k = (sh_degree + 1) ** 2
    return Gaussians(
        means=torch.randn(n, 3, generator=g, dtype=dtype) * spread,
        quats=torch.randn(n, 4, generator=g, dtype=dtype),
        scales=torch.rand(n, 3, generator=g, dtype=dtype) * 0.3 + 0.01,
        opacities=torch.rand(n, generator=g, dtype=dtype),
        sh=torch.randn(n, k, 3, generator=g, dtype=dtype) * 0.4,
    )


def camera(width=37, height=29, f=40.0, fy=None, cx=None, cy=None, eye=(0.3, 0.2, -4.0)) -> Camera:
    cam = Camera.look_at(eye, (0, 0, 0), (0, -1, 0), f, width, height, fy=fy)
    K = cam.K.clone()
    K[0, 2] = width / 2 if cx is None else cx
    K[1, 2] = height / 2 if cy is None else cy
    return Camera(K, cam.world_to_cam, width, height)


def with_grad(g: Gaussians) -> tuple[Gaussians, list[torch.Tensor]]:
    params = [t.detach().clone().requires_grad_(True) for t in g.tensors().values()]
    return Gaussians(*params), params


def loss_weights(h: int, w: int, dtype=F64, seed=1):
    gen = torch.Generator().manual_seed(seed)
    return [torch.randn(*s, generator=gen, dtype=dtype) for s in ((3, h, w), (h, w), (h, w))]


def weighted(outs, weights):
    return sum((o * w).sum() for o, w in zip(outs, weights))


CASES = [
    dict(n=300, sh=0, cam=dict()),
    dict(n=300, sh=1, cam=dict(width=40, height=23)),
    dict(n=200, sh=2, cam=dict(cx=12.3, cy=20.7)),  # off-centre principal point (lens shift)
    dict(n=250, sh=3, cam=dict(f=30.0, fy=45.0, width=33, height=47)),
    dict(n=150, sh=3, cam=dict(width=1, height=1)),
]


@pytest.mark.parametrize("case", CASES, ids=[f"sh{c['sh']}-{i}" for i, c in enumerate(CASES)])
def test_fast_path_matches_twin_forward_and_backward_f64(case):
    """Tolerance: 1e-9 absolute on images and gradients in float64 (seen: ~1e-13)."""
    cam = camera(**case["cam"])
    g, params = with_grad(random_gaussians(case["n"], case["sh"], seed=case["n"]))
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=F64)
    fast = render(g, cam, background=bg)
    ref = render_reference(g, cam, bg)
    for a, b in zip((fast.rgb, fast.alpha, fast.depth), ref):
        assert a.shape == b.shape
        torch.testing.assert_close(a, b, atol=1e-9, rtol=0)
    assert fast.alpha.max() > 0.5  # the scene is really in view
    weights = loss_weights(cam.height, cam.width)
    g_fast = torch.autograd.grad(weighted((fast.rgb, fast.alpha, fast.depth), weights), params)
    g_ref = torch.autograd.grad(weighted(ref, weights), params)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "sh"), g_fast, g_ref):
        assert b.abs().max() > 0, name
        torch.testing.assert_close(
            a, b, atol=1e-9 * max(1.0, b.abs().max().item()), rtol=0, msg=name
        )


def test_fast_path_float32_close_to_twin_float64():
    """float32 fast path vs float64 twin: images within 2e-5 for >= 99.9% of pixels."""
    cam = camera(width=48, height=40)
    g64 = random_gaussians(400, 2, seed=3)
    fast = render(g64.to(dtype=torch.float32), cam)
    ref_rgb, ref_alpha, _ = render_reference(g64, cam)
    err = (fast.rgb.double() - ref_rgb).abs()
    assert fast.rgb.dtype == torch.float32
    assert (err > 2e-5).float().mean() < 1e-3
    assert err.max() < 0.05  # a rare 1/255 or 1e-4 threshold flip is the most it may differ by
    torch.testing.assert_close(fast.alpha.double(), ref_alpha, atol=0.05, rtol=0)


def test_single_gaussian_matches_analytic_value():
    """An isotropic Gaussian facing the camera: alpha = o·exp(-d²/2(σ²+0.3)) at every pixel."""
    f, z, sigma_world, o = 50.0, 2.0, 0.08, 0.7
    cam = Camera.from_intrinsics(f, f, 16.0, 16.0, 32, 32)
    g = Gaussians.from_colors(
        torch.tensor([[0.0, 0.0, z]], dtype=F64),
        torch.tensor([[0.2, 0.4, 0.6]], dtype=F64),
        torch.full((1, 3), sigma_world, dtype=F64),
        torch.tensor([o], dtype=F64),
    )
    out = render(g, cam)
    var = (f * sigma_world / z) ** 2 + 0.3
    v, u = torch.meshgrid(
        torch.arange(32, dtype=F64) + 0.5, torch.arange(32, dtype=F64) + 0.5, indexing="ij"
    )
    alpha = o * torch.exp(-((u - 16) ** 2 + (v - 16) ** 2) / (2 * var))
    alpha = torch.where(alpha >= 1 / 255, alpha, torch.zeros_like(alpha))
    torch.testing.assert_close(out.alpha, alpha, atol=1e-12, rtol=0)
    torch.testing.assert_close(
        out.rgb, alpha * torch.tensor([0.2, 0.4, 0.6], dtype=F64)[:, None, None], atol=1e-12, rtol=0
    )
    torch.testing.assert_close(
        out.depth[alpha > 0], torch.full_like(out.depth[alpha > 0], z), atol=1e-12, rtol=0
    )


def test_opaque_plane_gives_its_depth_and_colour():
    n = 81
    xs = torch.linspace(-4, 4, n, dtype=F64)
    gx, gy = torch.meshgrid(xs, xs, indexing="ij")
    means = torch.stack([gx.flatten(), gy.flatten(), torch.full((n * n,), 3.0, dtype=F64)], -1)
    g = Gaussians.from_colors(
        means,
        torch.full((n * n, 3), 0.25, dtype=F64),
        torch.full((n * n, 3), 0.15, dtype=F64),
        torch.ones(n * n, dtype=F64),
    )
    out = render(g, Camera.from_intrinsics(20, 20, 16, 12, 32, 24), background=torch.ones(3))
    assert out.alpha.min() > 0.999
    torch.testing.assert_close(out.depth, torch.full_like(out.depth, 3.0), atol=1e-9, rtol=0)
    assert (out.rgb - 0.25).abs().max() < 1e-3  # 1 - alpha of white background leaks at most


def test_view_dependent_colour_follows_sh_degree_1():
    """Y_1 coefficients on one channel: colour = 0.5 + C0·c0 − C1·y·c1 + C1·z·c2 − C1·x·c3."""
    sh = torch.zeros(1, 4, 3, dtype=F64)
    sh[0, 3, 0] = 0.5  # red varies with the x component of the view direction
    g = Gaussians(
        torch.tensor([[0.0, 0.0, 0.0]], dtype=F64),
        torch.tensor([[1.0, 0, 0, 0]], dtype=F64),
        torch.full((1, 3), 0.5, dtype=F64),
        torch.tensor([0.9], dtype=F64),
        sh,
    )
    for eye_x in (-3.0, 3.0):
        cam = Camera.look_at((eye_x, 0, -3), (0, 0, 0), (0, -1, 0), 20, 16, 16)
        out = render(g, cam)
        d = -torch.tensor([eye_x, 0.0, -3.0], dtype=F64)
        d = d / d.norm()
        red = max(0.0, 0.5 - 0.4886025119029199 * d[0].item() * 0.5)
        centre_alpha = out.alpha[7:9, 7:9].mean()
        torch.testing.assert_close(
            out.rgb[0, 7:9, 7:9].mean() / centre_alpha,
            torch.tensor(red, dtype=F64),
            atol=1e-9,
            rtol=0,
        )


# ---- numerical stability ------------------------------------------------------------------


def _one(means, scales, opacity=0.8, quat=(1.0, 0.0, 0.0, 0.0), n=1, sh_degree=1):
    means = torch.as_tensor(means, dtype=torch.float32).reshape(-1, 3).expand(n, 3).clone()
    k = (sh_degree + 1) ** 2
    sh = torch.zeros(n, k, 3)
    sh[:, 0] = rgb_to_sh0(torch.tensor([0.9, 0.5, 0.1]))
    sh[:, 1:] = 0.1
    return Gaussians(
        means,
        torch.tensor([quat], dtype=torch.float32).expand(n, 4).clone(),
        torch.as_tensor(scales, dtype=torch.float32).reshape(-1, 3).expand(n, 3).clone(),
        torch.full((n,), float(opacity)),
        sh,
    )


HARD = {
    "needle_edge_on": (_one([0, 0, 2], [1.0, 1e-7, 1e-7]), {}),
    "needle_rotated": (_one([0.1, 0, 2], [2.0, 1e-9, 1e-9], quat=(0.92, 0.1, 0.3, 0.2)), {}),
    "zero_scale": (_one([0, 0, 2], [0.0, 0.0, 0.0]), {}),
    "tiny_scale_1e-12": (_one([0, 0, 2], [1e-12, 1e-12, 1e-12]), {}),
    "huge_covers_frame": (_one([0, 0, 2], [1e4, 1e4, 1e4], opacity=0.5), {}),
    "behind_camera": (_one([0, 0, -2], [0.3, 0.3, 0.3]), {}),
    "at_camera_centre": (_one([0, 0, 0], [0.3, 0.3, 0.3]), {}),
    "just_past_near_plane": (_one([0, 0, 0.0100001], [0.01, 0.01, 0.01]), {}),
    "far_1e7": (_one([10.0, 0, 1e7], [100.0, 100.0, 100.0]), {}),
    "many_coincident": (_one([0, 0, 2], [0.1, 0.1, 0.1], n=500), {}),
    "opacity_0": (_one([0, 0, 2], [0.1, 0.1, 0.1], opacity=0.0), {}),
    "opacity_1": (_one([0, 0, 2], [0.1, 0.1, 0.1], opacity=1.0), {}),
    "empty": (Gaussians.empty(sh_degree=1), {}),
    "image_1x1": (_one([0, 0, 2], [0.1, 0.1, 0.1]), dict(width=1, height=1, f=1.0)),
    "odd_size": (_one([0, 0, 2], [0.1, 0.1, 0.1]), dict(width=17, height=3)),
    "focal_1e-2": (_one([0, 0, 2], [0.5, 0.5, 0.5]), dict(f=1e-2)),
    "focal_1e5": (_one([0, 0, 2], [0.5, 0.5, 0.5]), dict(f=1e5)),
    "focal_1e5_off_axis": (_one([1, 0.5, 2], [1e-3, 1e-3, 1e-3]), dict(f=1e5)),
}


@pytest.mark.parametrize("name", list(HARD))
def test_hard_cases_finite_images_and_gradients(name):
    g, cam_kwargs = HARD[name]
    kw = dict(width=24, height=20, f=20.0) | cam_kwargs
    cam = Camera.from_intrinsics(
        kw["f"], kw["f"], kw["width"] / 2, kw["height"] / 2, kw["width"], kw["height"]
    )
    g, params = with_grad(g)
    bg = torch.tensor([0.1, 0.2, 0.3])
    out = render(g, cam, background=bg)
    for t in (out.rgb, out.alpha, out.depth):
        assert torch.isfinite(t).all()
    assert out.alpha.min() >= 0 and out.alpha.max() <= 1
    if name == "empty" or name in ("behind_camera", "at_camera_centre", "opacity_0"):
        torch.testing.assert_close(out.rgb, bg[:, None, None].expand_as(out.rgb))
        assert out.alpha.max() == 0
    if name in ("huge_covers_frame", "opacity_1", "many_coincident", "just_past_near_plane"):
        assert out.alpha.max() > 0.4
    loss = out.rgb.square().sum() + out.alpha.sum() + out.depth.sum()
    if loss.requires_grad:
        for grad in torch.autograd.grad(loss, params, allow_unused=True):
            assert grad is None or torch.isfinite(grad).all(), name


@pytest.mark.parametrize(
    "name",
    [
        "needle_rotated",
        "huge_covers_frame",
        "many_coincident",
        "focal_1e5",
        "just_past_near_plane",
        "odd_size",
    ],
)
def test_hard_cases_agree_with_twin(name):
    g, cam_kwargs = HARD[name]
    kw = dict(width=24, height=20, f=20.0) | cam_kwargs
    cam = Camera.from_intrinsics(
        kw["f"], kw["f"], kw["width"] / 2, kw["height"] / 2, kw["width"], kw["height"]
    )
    g64 = g.to(dtype=F64)
    fast = render(g64, cam)
    ref = render_reference(g64, cam)
    for a, b in zip((fast.rgb, fast.alpha, fast.depth), ref):
        torch.testing.assert_close(a, b, atol=1e-7, rtol=1e-7)


def test_invalid_input_raises_value_error():
    g = _one([0, 0, 2], [0.1, 0.1, 0.1])
    cam = Camera.from_intrinsics(20, 20, 12, 10, 24, 20)
    for field, value in (("means", math.nan), ("scales", -1.0), ("opacities", math.inf)):
        bad = Gaussians(**{k: v.clone() for k, v in g.tensors().items()})
        getattr(bad, field).view(-1)[0] = value
        with pytest.raises(ValueError, match=field):
            render(bad, cam)
    with pytest.raises(ValueError, match="background"):
        render(g, cam, background=torch.tensor([0.0, 1.0]))
    with pytest.raises(ValueError, match="backend"):
        render(g, cam, backend="opengl")


def test_visible_mask_and_background_gradient():
    g = random_gaussians(100, 0, seed=5)
    cam = camera()
    bg = torch.tensor([0.5, 0.5, 0.5], dtype=F64, requires_grad=True)
    out = render(g, cam, background=bg)
    (grad,) = torch.autograd.grad(out.rgb.sum(), bg)
    torch.testing.assert_close(grad, (1 - out.alpha).sum().expand(3), atol=1e-9, rtol=0)
    assert 0 < out.visible.sum() <= 100


def test_backward_is_bitwise_reproducible_with_threads_and_matches_one_thread():
    """The backward pass splits tiles between threads statically (thread k: tiles k, k+n, ...),
    so 2 threads give the same gradients on every run, and the same as 1 thread up to
    rounding (the per-thread buffers sum in another order)."""
    from prosplat.eval.demo_scene import demo_scene

    g, cams = demo_scene(size=48, n_inputs=2)
    g = g.to(dtype=torch.float64)

    def grads(threads: int) -> list[torch.Tensor]:
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            leaves = [t.detach().clone().requires_grad_(True) for t in g.tensors().values()]
            out = render(Gaussians(*leaves), cams[1])
            (out.rgb.square().sum() + out.depth.sum()).backward()
            return [t.grad for t in leaves]
        finally:
            torch.set_num_threads(before)

    a, b, one = grads(2), grads(2), grads(1)
    for x, y, z in zip(a, b, one):
        assert torch.equal(x, y)
        assert torch.allclose(x, z, rtol=1e-10, atol=1e-12)
