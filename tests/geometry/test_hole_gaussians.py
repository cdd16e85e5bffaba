"""prosplat.geometry.hole_gaussians: a Gaussian for every pixel a scene leaves uncovered in a known view."""

from __future__ import annotations

import pytest
import torch

from prosplat import Gaussians, render
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
from prosplat.geometry.hole_gaussians import HOLE_ALPHA, backdrop_depth, hole_gaussians
from prosplat.metrics import psnr

SIZE = 32


@pytest.fixture(scope="module")
def views():
    """3 orbit views of the analytic demo scene 60° apart and their exact images; the scene
    is view 0's pixel-aligned Gaussians with the left half of its pixels dropped, so views
    1 and 2 both miss a part of it."""
    cams = orbit_cameras(3, SIZE, SIZE, arc_deg=60.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    g0 = pixel_aligned_gaussians(cams[:1])
    u = (torch.arange(SIZE * SIZE) % SIZE).to(torch.int64)  # column of each Gaussian's pixel
    return dict(cams=cams, images=images, start=g0[u >= SIZE // 2])


def test_every_hole_pixel_gets_its_gaussian_on_its_ray(views):
    """One new Gaussian per hole pixel (alpha below HOLE_ALPHA), centred on that pixel at the
    farthest depth the view's covered pixels reach, with the image's colour at that pixel;
    the given Gaussians come first, unchanged."""
    cam, image, start = views["cams"][1], views["images"][1], views["start"]
    out = render(start, cam)
    seed = out.alpha < HOLE_ALPHA
    assert 50 < int(seed.sum()) < SIZE * SIZE  # the case at hand has holes and cover
    far = float(out.depth[~seed].max())
    assert backdrop_depth(out.depth, out.alpha) == far
    assert far > float(out.depth[~seed].median()) * 1.05  # a backdrop, not a typical depth

    g = hole_gaussians(start, image[None], [cam])
    n = len(start)
    assert len(g) == n + int(seed.sum())
    for name in ("means", "scales", "opacities", "sh"):
        assert torch.equal(getattr(g, name)[:n], getattr(start, name)), name
    new = g[torch.arange(n, len(g))]
    uv, z = cam.project(new.means)
    torch.testing.assert_close(uv, cam.pixel_centers(uv.dtype)[seed])
    torch.testing.assert_close(z, torch.full_like(z, far))
    colour = new.sh[:, 0] * 0.28209479177387814 + 0.5
    torch.testing.assert_close(colour, image[:, seed].T.to(colour.dtype))


def test_the_seeded_view_is_covered_and_closer_to_its_image(views):
    """After seeding, no pixel of the view is left a hole, and its render is much closer to
    its image than the scene's render on black."""
    cam, image, start = views["cams"][1], views["images"][1], views["start"]
    before = render(start, cam)
    after = render(hole_gaussians(start, image[None], [cam]), cam)
    assert float(before.alpha.min()) < 0.1
    assert float(after.alpha.min()) >= HOLE_ALPHA
    assert float(psnr(after.rgb, image)) > float(psnr(before.rgb, image)) + 6.0


def test_views_in_order_seed_a_shared_hole_once(views):
    """Each view is rendered with the Gaussians seeded for the views before it: seeding
    views 1 and 2 together adds fewer than seeding each alone and adding up, and seeding a
    view twice adds nothing the second time."""
    cams, images, start = views["cams"], views["images"], views["start"]
    one = len(hole_gaussians(start, images[1:2], cams[1:2])) - len(start)
    two = len(hole_gaussians(start, images[2:3], cams[2:3])) - len(start)
    both = len(hole_gaussians(start, images[1:3], cams[1:3])) - len(start)
    assert 0 < both < one + two
    again = hole_gaussians(start, images[[1, 1]], [cams[1], cams[1]])
    assert len(again) == len(start) + one


def test_nothing_to_seed():
    """A view the Gaussians cover completely, or one where they cover nothing (no depth to
    go on), adds no Gaussian."""
    cams = orbit_cameras(2, SIZE, SIZE, arc_deg=10.0)
    g = pixel_aligned_gaussians(cams)
    images = torch.stack([render(g, c).rgb for c in cams]).clamp(0, 1)
    assert len(hole_gaussians(g, images[:1], cams[:1])) == len(g)
    behind = Gaussians.trusted(
        g.means - 100 * cams[0].forward.to(g.means), g.quats, g.scales, g.opacities, g.sh
    )  # every Gaussian behind the camera
    assert len(hole_gaussians(behind, images[:1], cams[:1])) == len(g)
    out = render(behind, cams[0])
    assert backdrop_depth(out.depth, out.alpha) is None


def test_bad_views_are_refused(views):
    cams, images, start = views["cams"], views["images"], views["start"]
    with pytest.raises(ValueError, match="one camera each"):
        hole_gaussians(start, images[:2], cams[:1])
    with pytest.raises(ValueError, match="an image of"):
        hole_gaussians(start, images[:1, :, :16], cams[:1])


def test_holes_showing_the_background_get_none(views):
    """With the background the images were composited over (a NeRF-synthetic set's white),
    a hole pixel that shows it gets no Gaussian; the other holes still do."""
    cam, start = views["cams"][1], views["start"]
    image = views["images"][1].clone()
    image[:, :, : SIZE // 2] = 1.0  # the left half shows a white background
    hole = render(start, cam).alpha < HOLE_ALPHA
    shows_bg = torch.zeros_like(hole)
    shows_bg[:, : SIZE // 2] = True
    assert int((hole & shows_bg).sum()) > 20 and int((hole & ~shows_bg).sum()) > 20
    g = hole_gaussians(start, image[None], [cam], background=(1.0, 1.0, 1.0))
    assert len(g) == len(start) + int((hole & ~shows_bg).sum())
    assert len(hole_gaussians(start, image[None], [cam])) == len(start) + int(hole.sum())
