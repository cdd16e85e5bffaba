"""prosplat.geometry.depth_edges and prosplat.pipeline.edges: depth edges found and resolved.

The references: an exactly ray-cast scene (spheres in front of a wall and a floor,
:mod:`prosplat.eval.demo_scene`) whose true depth maps are blurred the way a generator's
are (matched at a quarter of the size, upsampled bilinearly), and the rasterizer's depth
of the Gaussians against the ray-cast truth at views between the inputs."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from prosplat import render
from prosplat.eval.baselines.plane_sweep import gaussians_from_depths
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians, raycast
from prosplat.generator import GeneratorOutput
from prosplat.geometry.depth_edges import EdgeOptions, depth_edges, resolve_depth_edges
from prosplat.metrics import psnr
from prosplat.metrics.depth import floater_share
from prosplat.pipeline.edges import resolve_output
from prosplat.render.hole_fill import fill_holes

SIZE = 128
FACTOR = 4  # the generator matched at SIZE / FACTOR


def blurred(depths: torch.Tensor, factor: int = FACTOR) -> torch.Tensor:
    """``depths`` [V,H,W] as a generator matching at 1/factor of the size gives them: averaged
    down, then bilinearly up (the ramps across every silhouette)."""
    h, w = depths.shape[-2:]
    small = F.avg_pool2d(depths[:, None], factor)
    return F.interpolate(small, size=(h, w), mode="bilinear", align_corners=False)[:, 0]


@pytest.fixture(scope="module")
def orbit():
    """7 cameras on an arc: the even ones are inputs, the odd ones targets between them;
    exact images and depths of each."""
    cams = orbit_cameras(7, SIZE, SIZE, arc_deg=40.0)
    truth = pixel_aligned_gaussians(orbit_cameras(9, 2 * SIZE, 2 * SIZE, arc_deg=40.0))
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    depths = torch.stack([raycast(c)[0] for c in cams]).float()
    return cams, images, depths


def as_output(cams, images, depths) -> GeneratorOutput:
    """A GeneratorOutput (B = 1): a pixel's Gaussian at ``depths``, its colour, a pixel wide."""
    g = gaussians_from_depths(images, cams, depths, torch.ones_like(depths))
    conf = torch.ones_like(depths)[None]
    return GeneratorOutput(
        g.means[None], g.quats[None], g.scales[None], g.opacities[None], g.sh[None],
        depths[None], conf,
    )  # fmt: skip


def two_surfaces(h: int = 24, w: int = 32, cut: int = 13) -> torch.Tensor:
    """[1,h,w]: depth 2 left of column ``cut``, 4 from it on."""
    d = torch.full((1, h, w), 4.0)
    d[..., :cut] = 2.0
    return d


def test_a_ramp_between_two_surfaces_is_found_and_resolved_and_nothing_else_moves():
    """A blurred step: the pixels inside the ramp are found; snapped, every one lands on 2 or
    4 (none in between), on the side of the nearer one in log depth; dropped, the depth stays
    and exactly those pixels go. The flat parts are unchanged to the bit either way."""
    true = two_surfaces()
    ramp = blurred(true, 4)
    mid = (ramp > 2.2) & (ramp < 3.6)
    assert int(mid.sum()) > 24  # the ramp exists
    edge = depth_edges(ramp, scale=4)
    assert bool(edge[mid].all()) and not bool(edge[(ramp - true).abs() < 1e-6].any())
    new, dropped = resolve_depth_edges(ramp, EdgeOptions(remedy="snap"), scale=4)
    assert not bool(dropped.any())
    # onto the surfaces read one matching pixel away (the ramp's ends: within 10 %)
    assert not bool(((new > 2.2) & (new < 3.6))[edge].any())
    nearer = ramp.log() - math.log(2.0) <= math.log(4.0) - ramp.log()
    assert torch.equal(new[edge] < 3, nearer[edge])
    assert torch.equal(new[~edge], ramp[~edge])
    same, dropped = resolve_depth_edges(ramp, EdgeOptions(remedy="drop"), scale=4)
    assert torch.equal(same, ramp) and torch.equal(dropped, edge)
    _, grown = resolve_depth_edges(ramp, EdgeOptions(remedy="drop", grow=1.0), scale=4)
    assert bool(grown[edge].all()) and int(grown.sum()) > int(edge.sum())


def test_exact_depth_has_no_ramps():
    """A true step (the silhouette's last pixel is steep on one side only) is no ramp."""
    assert not bool(depth_edges(two_surfaces(), scale=1).any())
    assert not bool(depth_edges(two_surfaces(), scale=4).any())


def test_slanted_surfaces_and_missing_depth_are_left_alone():
    """A floor seen at a slant (1.5 % per input pixel, 6 % per matching pixel) has no edge;
    pixels without a depth (0, NaN) keep it and do not make their neighbours edges."""
    cols = torch.arange(32, dtype=torch.float32)
    slant = (3.0 * torch.exp(0.015 * cols))[None, None, :].expand(1, 24, 32).clone()
    assert not bool(depth_edges(slant, scale=4).any())
    new, dropped = resolve_depth_edges(slant, EdgeOptions(remedy="snap"), scale=4)
    assert torch.equal(new, slant) and not bool(dropped.any())
    holed = slant.clone()
    holed[0, 5:9, 5:9] = 0.0
    holed[0, 15, 20] = float("nan")
    edge = depth_edges(holed, scale=4)
    new, _ = resolve_depth_edges(holed, EdgeOptions(remedy="snap"), scale=4)
    assert not bool(edge.any())
    assert torch.equal(new[holed > 0], holed[holed > 0])
    assert bool((new[0, 5:9, 5:9] == 0).all()) and bool(new[0, 15, 20].isnan())


def test_bad_options_and_inputs_raise_naming_the_fix():
    with pytest.raises(ValueError, match="jump"):
        EdgeOptions(jump=0)
    with pytest.raises(ValueError, match="grow"):
        EdgeOptions(grow=-1)
    with pytest.raises(ValueError, match="reach"):
        EdgeOptions(reach=float("nan"))
    with pytest.raises(ValueError, match="remedy"):
        EdgeOptions(remedy="shrink")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\[V,H,W\]"):
        resolve_depth_edges(two_surfaces()[0])


@pytest.mark.parametrize("remedy", ["drop", "snap"])
def test_curtains_at_silhouettes_stop_floating_in_front_of_the_truth(orbit, remedy, one_thread):
    """The spheres' silhouettes blurred as a generator's 4x-upsampled depth: at the views
    between the inputs, the share of pixels drawn > 10 % in front of the ray-cast depth
    (the ladder's floater figure) falls by more than half once the ramps are resolved, the
    filled views get better, and the Gaussians off the ramps are untouched."""
    cams, images, depths = orbit
    ins, targets = [0, 2, 4, 6], [1, 3, 5]
    in_cams = [cams[i] for i in ins]
    out = as_output(in_cams, images[ins], blurred(depths[ins]))
    resolved = resolve_output(out, in_cams, EdgeOptions(remedy=remedy), scale=FACTOR)
    floats, colour = [], []
    for t in targets:
        r0, r1 = render(out.gaussians(0), cams[t]), render(resolved.gaussians(0), cams[t])
        floats.append([floater_share(r.depth, depths[t], r.alpha) for r in (r0, r1)])
        colour.append([float(psnr(fill_holes(r.rgb, r.alpha), images[t])) for r in (r0, r1)])
    (f0, f1), (p0, p1) = torch.tensor(floats).mean(0), torch.tensor(colour).mean(0)
    assert f0 > 0.05, floats  # the curtains are there to remove (7.4 %)
    assert f1 < 0.5 * f0, floats  # drop 0.3 %, snap 3.0 %
    assert p1 > p0 + 2.0, colour  # 20.5 dB -> 24.0 (drop), 23.8 (snap)
    edge = depth_edges(blurred(depths[ins]), scale=FACTOR).reshape(-1)
    moved = (resolved.means[0] - out.means[0]).norm(dim=1) > 1e-5
    changed = moved | (resolved.opacities[0] != out.opacities[0])
    assert bool(changed.any()) and not bool(changed[~edge].any())


def test_resolve_output_takes_one_scene(orbit):
    cams, images, depths = orbit
    out = as_output(cams[:2], images[:2], depths[:2])
    two = GeneratorOutput(*(torch.cat([x, x]) for x in (
        out.means, out.quats, out.scales, out.opacities, out.sh, out.depths, out.confidence
    )))  # fmt: skip
    with pytest.raises(ValueError, match="one scene"):
        resolve_output(two, cams[:2])
