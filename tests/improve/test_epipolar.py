"""Fundamental matrices and epipolar distances, checked against independent constructions."""

from __future__ import annotations

import math

import pytest
import torch

from prosplat import Camera
from prosplat.improve.epipolar import (
    epipolar_distances,
    fundamental_matrices,
    fundamental_matrix,
)


def _camera(eye, target, fx, fy, cx, cy, w, h) -> Camera:
    """A look-at camera with arbitrary intrinsics (fx ≠ fy, off-centre principal point)."""
    base = Camera.look_at(eye, target, (0.0, -1.0, 0.0), fx, w, h)
    K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return Camera(K, base.world_to_cam, w, h)


def _random_pair(gen: torch.Generator) -> tuple[Camera, Camera]:
    def rnd(*shape):
        return torch.rand(*shape, generator=gen, dtype=torch.float64)

    cams = []
    for _ in range(2):
        w, h = int(32 + 96 * rnd(1)), int(24 + 72 * rnd(1))
        eye = (rnd(3) - 0.5) * 6.0 + torch.tensor([0.0, 0.0, -4.0], dtype=torch.float64)
        look = (rnd(3) - 0.5) * 0.5
        fx = float(0.6 + 0.8 * rnd(1)) * w
        fy = fx * float(0.8 + 0.4 * rnd(1))
        cx, cy = w * float(0.3 + 0.4 * rnd(1)), h * float(0.3 + 0.4 * rnd(1))
        cams.append(_camera(eye, look, fx, fy, cx, cy, w, h))
    return cams[0], cams[1]


def _visible_points(cams: list[Camera], n: int, gen: torch.Generator) -> torch.Tensor:
    """``n`` random points near the origin seen by every camera in ``cams``."""
    pts = (torch.rand(20 * n, 3, generator=gen, dtype=torch.float64) - 0.5) * 2.0
    keep = torch.ones(len(pts), dtype=torch.bool)
    for cam in cams:
        uv, z = cam.project(pts)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0)
        keep &= (z > 0.1) & inside & (uv[:, 1] < cam.height)
    assert keep.sum() >= n, "test setup: too few points visible in both views"
    return pts[keep][:n]


def _homog(uv: torch.Tensor) -> torch.Tensor:
    return torch.cat([uv, torch.ones_like(uv[..., :1])], -1)


def _line_through_ray(target: Camera, ref: Camera, uv_t: torch.Tensor) -> torch.Tensor:
    """Brute force: the line through the reference projections of two points on the target ray.

    Returns [M, 3] lines scaled so that (a, b) is a unit vector.
    """
    near = target.unproject(uv_t, torch.full(uv_t.shape[:-1], 0.5, dtype=torch.float64))
    far = target.unproject(uv_t, torch.full(uv_t.shape[:-1], 7.0, dtype=torch.float64))
    p1, _ = ref.project(near)
    p2, _ = ref.project(far)
    line = torch.linalg.cross(_homog(p1), _homog(p2))
    return line / line[:, :2].norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("seed", range(8))
def test_fundamental_matrix_satisfies_epipolar_constraint(seed: int) -> None:
    gen = torch.Generator().manual_seed(seed)
    target, ref = _random_pair(gen)
    F = fundamental_matrix(target, ref)
    assert F.dtype == torch.float64 and F.shape == (3, 3)
    assert math.isclose(float(F.norm()), 1.0, rel_tol=1e-12)

    pts = _visible_points([target, ref], 50, gen)
    x_t = _homog(target.project(pts)[0])  # [50, 3]
    x_r = _homog(ref.project(pts)[0])
    lines = x_t @ F.T  # [50, 3], F x_t
    residual = (x_r * lines).sum(-1)
    assert residual.abs().max() < 1e-9 * x_r.norm(dim=-1).max() * x_t.norm(dim=-1).max()
    dist = residual.abs() / lines[:, :2].norm(dim=-1)
    assert dist.max() < 1e-3

    # The same line as the brute-force construction through two points on the target ray.
    brute = _line_through_ray(target, ref, x_t[:, :2])
    ours = lines / lines[:, :2].norm(dim=-1, keepdim=True)
    sign = torch.sign((brute * ours).sum(-1, keepdim=True))
    torch.testing.assert_close(ours * sign, brute, atol=1e-7, rtol=0)


@pytest.mark.parametrize(
    "eye_ref",
    [(0.0, 0.0, -4.0), (1e6, -2e6, 3e6)],
    ids=["near-origin", "far-from-origin"],
)
def test_vanishing_baseline_gives_zero_and_invalid(eye_ref) -> None:
    eye = torch.tensor(eye_ref, dtype=torch.float64)
    target = Camera.look_at(eye, eye + torch.tensor([0.0, 0.0, 1.0]), (0, -1, 0), 40.0, 64, 48)
    rotated = Camera.look_at(eye, eye + torch.tensor([1.0, 0.2, 1.0]), (0, -1, 0), 50.0, 32, 32)
    for ref in (target, rotated):  # coincident, then pure rotation
        F = fundamental_matrix(target, ref)
        assert torch.equal(F, torch.zeros(3, 3, dtype=torch.float64))
        d, valid = epipolar_distances(F[None], (6, 8), (4, 4), 8.0)
        assert not valid.any() and torch.equal(d, torch.zeros_like(d))


def test_batched_equals_single_and_accepts_float32() -> None:
    gen = torch.Generator().manual_seed(123)
    pairs = [_random_pair(gen) for _ in range(5)]
    pairs.append((pairs[0][0], pairs[0][0]))  # a coincident pair in the batch
    K_t = torch.stack([t.K for t, _ in pairs]).float()
    w_t = torch.stack([t.world_to_cam for t, _ in pairs]).float()
    K_r = torch.stack([r.K for _, r in pairs]).float()
    w_r = torch.stack([r.world_to_cam for _, r in pairs]).float()
    batched = fundamental_matrices(K_t, w_t, K_r, w_r)
    assert batched.dtype == torch.float64 and batched.shape == (6, 3, 3)
    for b, (t, r) in enumerate(pairs[:5]):
        single = fundamental_matrix(t, r)
        sign = torch.sign((single * batched[b]).sum())
        # float32 poses carry ~1e-7 relative error into F
        torch.testing.assert_close(batched[b] * sign, single, atol=1e-4, rtol=0)
    assert torch.equal(batched[5], torch.zeros(3, 3, dtype=torch.float64))


def test_fundamental_matrices_rejects_bad_input() -> None:
    eye4 = torch.eye(4)[None]
    K = torch.tensor([[50.0, 0, 16], [0, 50, 16], [0, 0, 1]])[None]
    with pytest.raises(ValueError, match="w2c_tgt"):
        fundamental_matrices(K, torch.eye(3)[None], K, eye4)
    with pytest.raises(ValueError, match="batch"):
        fundamental_matrices(K, eye4, K.repeat(2, 1, 1), eye4.repeat(2, 1, 1))
    bad = eye4.clone()
    bad[0, 0, 3] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        fundamental_matrices(K, eye4, K, bad)


def test_epipolar_distances_match_true_correspondences() -> None:
    stride = 8.0
    target = _camera((0.4, -0.3, -4.0), (0.0, 0.0, 0.0), 70.0, 64.0, 30.0, 26.0, 96, 64)
    ref = _camera((-1.8, 0.5, -3.5), (0.2, -0.1, 0.0), 60.0, 66.0, 50.0, 30.0, 80, 72)
    F = fundamental_matrix(target, ref)
    t_hw, r_hw = (8, 12), (9, 10)
    d, valid = epipolar_distances(F[None], t_hw, r_hw, stride)
    assert valid.all() and d.shape == (1, 96, 90) and torch.isfinite(d).all()

    # Lift every target cell centre to 3D at random depths and project it into the reference.
    gen = torch.Generator().manual_seed(0)
    rows, cols = torch.meshgrid(torch.arange(8.0), torch.arange(12.0), indexing="ij")
    uv_t = torch.stack([cols, rows], -1).reshape(-1, 2).double() * stride + stride / 2
    depth = 3.0 + 2.0 * torch.rand(96, generator=gen, dtype=torch.float64)
    uv_r, z = ref.project(target.unproject(uv_t, depth))
    cell = torch.floor(uv_r / stride).long()
    seen = (z > 0) & (cell[:, 0] >= 0) & (cell[:, 0] < 10) & (cell[:, 1] >= 0) & (cell[:, 1] < 9)
    assert seen.sum() > 30
    j = cell[:, 1] * 10 + cell[:, 0]
    i = torch.arange(96)
    assert (d[0, i[seen], j[seen]] < stride).all()  # within half a cell diagonal, in fact

    # Every entry equals the brute-force point-to-line distance.
    lines = _line_through_ray(target, ref, uv_t)  # [96, 3]
    rr, cc = torch.meshgrid(torch.arange(9.0), torch.arange(10.0), indexing="ij")
    uv_r_cells = torch.stack([cc, rr], -1).reshape(-1, 2).double() * stride + stride / 2
    brute = (lines @ _homog(uv_r_cells).T).abs()
    torch.testing.assert_close(d[0], brute, atol=1e-6, rtol=1e-9)


def test_degenerate_rows_at_the_epipole_are_finite_zero() -> None:
    # The reference sits straight behind the target on its optical axis: the target's epipole
    # is its principal point, placed on the centre of feature cell (3, 2) at stride 8.
    target = _camera((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), 50.0, 50.0, 28.0, 20.0, 64, 48)
    ref = _camera((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 50.0, 50.0, 32.0, 24.0, 64, 48)
    F = fundamental_matrix(target, ref)
    d, valid = epipolar_distances(F[None], (6, 8), (6, 8), 8.0)
    assert valid.all() and torch.isfinite(d).all()
    epipole_row = 2 * 8 + 3
    assert torch.equal(d[0, epipole_row], torch.zeros(48, dtype=d.dtype))
    others = torch.cat([d[0, :epipole_row], d[0, epipole_row + 1 :]])
    assert (others.amax(-1) > 1.0).all()  # every other row is a real line


def test_epipolar_distances_rejects_bad_input() -> None:
    F = torch.zeros(1, 3, 3)
    with pytest.raises(ValueError, match="stride"):
        epipolar_distances(F, (2, 2), (2, 2), 0.0)
    with pytest.raises(ValueError, match="target_hw"):
        epipolar_distances(F, (0, 2), (2, 2), 8.0)
    with pytest.raises(ValueError, match=r"\[B, 3, 3\]"):
        epipolar_distances(torch.zeros(3, 3), (2, 2), (2, 2), 8.0)
