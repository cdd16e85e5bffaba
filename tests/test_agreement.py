"""The views' agreement maps (prosplat.generator.agreement) on a textured plane seen by two
cameras, where the right depth, a floater in front and a point behind are known exactly;
and the grown generator that feeds them to its Gaussian adapter."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from test_generator import SMALL, grown_then_trained
from test_image_cost import _plane_image, _two_views

from prosplat.generator.adapter import GaussianAdapter
from prosplat.generator.agreement import AGREEMENT_CHANNELS, view_agreement
from prosplat.generator.cost_volume import nearest_views
from prosplat.train.generator import TrainConfig

W, H, Z = 48, 40, 3.0


def _plane_depths(K: torch.Tensor, w2c: torch.Tensor) -> torch.Tensor:
    """[1,V,H,W] each camera's depth (z along its axis) of the world plane z = Z, by ray-plane
    intersection in float64."""
    out = []
    for k, m in zip(K[0].double(), w2c[0].double()):
        c2w = torch.linalg.inv(m)
        ys, xs = torch.meshgrid(
            torch.arange(H, dtype=torch.float64) + 0.5,
            torch.arange(W, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        pix = torch.stack([xs, ys, torch.ones_like(xs)], -1)  # [H,W,3]
        ray_cam = pix @ torch.linalg.inv(k).T  # [H,W,3] at camera depth 1
        ray_world = ray_cam @ c2w[:3, :3].T
        origin = c2w[:3, 3]
        out.append((Z - origin[2]) / ray_world[..., 2])  # camera depth of the hit (z_cam = 1)
    return torch.stack(out)[None].float()


@pytest.fixture(scope="module")
def plane():
    images, K, w2c = _two_views(W, H, Z, texture=_plane_image)
    return images, K, w2c, _plane_depths(K, w2c), nearest_views(w2c, 3)


def _centre(x: torch.Tensor) -> torch.Tensor:
    """The middle of the reference view (what the neighbour sees of it)."""
    return x[0, 0, :, H // 4 : 3 * H // 4, W // 4 : 3 * W // 4]


def test_the_right_depth_agrees_a_floater_is_seen_through_and_a_point_behind_is_hidden(plane):
    images, K, w2c, depth, nbr = plane
    right = _centre(view_agreement(images, depth, K, w2c, nbr))  # [3,h,w]
    assert right.shape[0] == AGREEMENT_CHANNELS
    assert right[0].median() < 0.02  # the same texture from both views
    assert (right[1] == 0).all() and (right[2] == 1).all()
    strided = images.transpose(-1, -2).contiguous().transpose(-1, -2)  # a training crop's layout
    assert not strided.is_contiguous()
    full = view_agreement(images, depth, K, w2c, nbr)
    torch.testing.assert_close(view_agreement(strided, depth, K, w2c, nbr), full)

    floater = depth.clone()
    floater[:, 0] *= 0.6  # the reference's points 40 % nearer: in front of the plane
    near = _centre(view_agreement(images, floater, K, w2c, nbr))
    assert (near[1] == 1).float().mean() > 0.95 and (near[2] == 0).all()
    assert near[0].median() > 5 * right[0].median()  # warped to the wrong place

    behind = depth.clone()
    behind[:, 0] *= 1.5  # behind the plane: the neighbour cannot see them
    hidden = _centre(view_agreement(images, behind, K, w2c, nbr))
    assert (hidden == 0).all()


def test_points_outside_every_neighbour_score_zero(plane):
    images, K, w2c, depth, nbr = plane
    away = w2c.clone()
    away[0, 1, 0, 3] += 1e3  # the neighbour moved far sideways: the plane leaves its image
    maps = view_agreement(images, depth, K, away, nbr)
    assert torch.isfinite(maps).all()
    assert (maps[0, 0] == 0).all()


def test_the_adapter_refuses_agreement_it_was_not_built_for():
    adapter = GaussianAdapter(4, 0, 0.25, 4.0, 0.5)
    feats, conf, rgb = torch.zeros(1, 4, 8, 8), torch.zeros(1, 1, 8, 8), torch.zeros(1, 3, 8, 8)
    depth, K, w2c = torch.ones(1, 8, 8), torch.eye(3)[None], torch.eye(4)[None]
    with pytest.raises(ValueError, match="agreement"):
        adapter(feats, conf, rgb, depth, K, w2c, torch.zeros(1, AGREEMENT_CHANNELS, 8, 8))
    grown = GaussianAdapter(4, 0, 0.25, 4.0, 0.5, AGREEMENT_CHANNELS)
    with pytest.raises(ValueError, match="agreement"):
        grown(feats, conf, rgb, depth, K, w2c)


def test_grow_view_agreement_reproduces_the_trained_network_then_learns():
    """Growing weights by the agreement maps gives the same Gaussians (their adapter inputs
    are zero-weighted), and one gradient step reaches those weights."""
    from prosplat.generator.grow import grow_view_agreement

    old, cfg, state, new = grown_then_trained(SMALL, grow_view_agreement)
    assert cfg == replace(SMALL, view_agreement=True)
    grad = new.adapter.hidden[0].weight.grad  # [R, R+4+A, 1, 1]
    assert grad[:, -AGREEMENT_CHANNELS:].abs().max() > 0
    with pytest.raises(ValueError, match="already"):
        grow_view_agreement(cfg, state)
    with pytest.raises(ValueError, match="grow_view_agreement"):
        TrainConfig(data="x", out="y", grow_view_agreement=True)
