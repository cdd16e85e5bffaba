"""prosplat.geometry.pixel_gaussians: one Gaussian per pixel on its ray, the pixel's colour and size."""

from __future__ import annotations

import pytest
import torch

from prosplat import render
from prosplat.eval.demo_scene import orbit_cameras
from prosplat.geometry.pixel_gaussians import pixel_gaussians
from prosplat.metrics import psnr

SIZE = 24


@pytest.fixture()
def view():
    cam = orbit_cameras(1, SIZE, SIZE)[0]
    y, x = torch.meshgrid(torch.linspace(0, 1, SIZE), torch.linspace(0, 1, SIZE), indexing="ij")
    image = torch.stack([x, y, 0.5 + 0.4 * torch.sin(6 * x * y)])  # [3,H,W] smooth
    depth = (2.0 + y + 0.5 * x).to(torch.float64)  # [H,W] a slanted plane
    depth[:, :5] = 0  # no surface: no Gaussian
    return cam, image, depth


def test_each_gaussian_projects_to_its_pixel_at_its_depth(view):
    """Row-major, one per pixel with depth: the mean projects onto the pixel centre at the
    pixel's depth; colour, scale (footprint x depth / fx) and opacity as given."""
    cam, image, depth = view
    g = pixel_gaussians(image, depth, cam, footprint=0.5, opacity=0.8)
    ok = depth > 0
    assert len(g) == int(ok.sum()) and g.means.dtype == torch.float64
    uv, z = cam.to(dtype=torch.float64).project(g.means)
    torch.testing.assert_close(uv, cam.pixel_centers(torch.float64)[ok])
    torch.testing.assert_close(z, depth[ok])
    torch.testing.assert_close(g.scales[:, 0], 0.5 * depth[ok] / cam.fx)
    assert torch.equal(g.scales[:, 0], g.scales[:, 2])
    torch.testing.assert_close(g.opacities, torch.full_like(depth[ok], 0.8))
    colors = (g.sh[:, 0] * 0.28209479177387814 + 0.5).float()  # SH band 0 back to RGB
    torch.testing.assert_close(colors, image.permute(1, 2, 0)[ok], atol=1e-6, rtol=0)


def test_opaque_pixel_gaussians_render_back_their_image(view):
    """From their own camera, opaque pixel-sized Gaussians reproduce a smooth image where
    they stand (the rasterizer agrees with the placement, not only the numbers above)."""
    cam, image, depth = view
    g = pixel_gaussians(image, depth.float(), cam, footprint=0.35, opacity=1.0)
    out = render(g, cam)
    assert float(out.alpha[:, 6:].min()) > 0.95  # column 5 borders the empty strip
    assert psnr(out.rgb[:, :, 6:], image[:, :, 6:]) > 25


def test_the_sh_degree_is_the_callers(view):
    cam, image, depth = view
    g = pixel_gaussians(image, depth, cam, footprint=0.7, opacity=0.9, sh_degree=2)
    assert g.sh.shape[1:] == (9, 3) and bool((g.sh[:, 1:] == 0).all())


def test_mismatched_shapes_are_refused(view):
    cam, image, depth = view
    with pytest.raises(ValueError, match=r"image \[3,H,W\] and depth \[H,W\]"):
        pixel_gaussians(image[:, :-1], depth, cam, 0.5, 1.0)
    with pytest.raises(ValueError, match="camera for a"):
        pixel_gaussians(image[:, :-1, :-1], depth[:-1, :-1], cam, 0.5, 1.0)
