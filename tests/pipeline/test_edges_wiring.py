"""ProSplat.depth_edges: the pipeline resolves the generator's depth ramps when asked, and
the command line switches it."""

from __future__ import annotations

import argparse

import pytest
import torch

from prosplat import render
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians
from prosplat.geometry.depth_edges import EdgeOptions, depth_edges

SIZE = 64


@pytest.fixture(scope="module")
def views():
    cams = orbit_cameras(4, SIZE, SIZE, arc_deg=40.0)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    return cams, images


def test_dropped_ramps_leave_the_reconstruction_and_the_rest_stays(views, shipped_generator):
    """The shipped generator at 32 px on 64-px inputs (Gaussians at 64 px, scale 2): with
    ``drop`` the ramp pixels of its depth are the extra transparent Gaussians the budget
    removes, and every other Gaussian is the one it was."""
    cams, images = views
    model = shipped_generator
    assert model.depth_edges is None  # off by default (BENCHMARKS.md, "Depth ramps")
    try:
        model.depth_edges = None
        plain = model.reconstruct(images, cams, generator_height=32, budget="all")
        model.depth_edges = EdgeOptions(remedy="drop")
        dropped = model.reconstruct(images, cams, generator_height=32, budget="all")
        kept = model.reconstruct(images, cams, generator_height=32)
    finally:
        model.depth_edges = None
    ramps = depth_edges(plain.depths, EdgeOptions(), scale=2).reshape(-1)
    assert int(ramps.sum()) > 0
    assert torch.equal(dropped.gaussians.opacities[ramps], torch.zeros(int(ramps.sum())))
    assert torch.equal(dropped.gaussians.means[~ramps], plain.gaussians.means[~ramps])
    assert kept.prune_stats["transparent"] >= int(ramps.sum())


def test_the_command_line_switches_it():
    from prosplat.cli.reconstruct import add_common_arguments, load_model

    parser = argparse.ArgumentParser()
    add_common_arguments(parser)
    for flags, want in (
        ([], None),
        (["--depth-edges", "off"], None),
        (["--depth-edges", "drop"], EdgeOptions()),
        (["--depth-edges", "snap"], EdgeOptions(remedy="snap")),
    ):
        args = parser.parse_args(["some/scene", "--out", "unused", *flags])
        args.improve = None
        assert load_model(args).depth_edges == want, flags
