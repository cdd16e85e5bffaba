"""Tests for ``prosplat.Gaussians``: validation, moves, concatenation, subsets, colours.

Expected values are built independently (by hand, with ``math``), not by calling the code
under test a second time.
"""

from __future__ import annotations

import math

import pytest
import torch

from prosplat.core.gaussians import SH_C0, Gaussians, rgb_to_sh0, sh0_to_rgb

FIELDS = ("means", "quats", "scales", "opacities", "sh")


def fields(n: int = 5, degree: int = 1, seed: int = 0) -> dict[str, torch.Tensor]:
    """Valid random tensors for ``n`` Gaussians of SH ``degree``."""
    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return {
        "means": torch.randn(n, 3, generator=gen),  # [N, 3]
        "quats": torch.randn(n, 4, generator=gen) + 0.1,  # [N, 4], not unit length
        "scales": torch.rand(n, 3, generator=gen) + 0.01,  # [N, 3]
        "opacities": torch.rand(n, generator=gen),  # [N]
        "sh": torch.randn(n, k, 3, generator=gen),  # [N, K, 3]
    }


def make(n: int = 5, degree: int = 1, seed: int = 0) -> Gaussians:
    return Gaussians(**fields(n, degree, seed))


def assert_same(a: Gaussians, b: Gaussians) -> None:
    for name in FIELDS:
        assert torch.equal(getattr(a, name), getattr(b, name)), name


# ---- validation ---------------------------------------------------------------------------
def test_valid_input_is_accepted_including_edge_values() -> None:
    t = fields(4)
    t["scales"][0] = 0.0  # a flat Gaussian is degenerate but valid
    t["opacities"][:2] = torch.tensor([0.0, 1.0])
    t["quats"][1] = torch.tensor([1e-30, 0.0, 0.0, 0.0])  # tiny but not zero
    g = Gaussians(**t)
    assert len(g) == 4


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_values_are_rejected_naming_the_field(field: str, bad: float) -> None:
    t = fields(5)
    t[field][2].reshape(-1)[-1] = bad  # one value of Gaussian 2 (a view: edits t)
    with pytest.raises(ValueError, match=rf"Gaussians\.{field} contains NaN or Inf in 1 of 5"):
        Gaussians(**t)


def test_negative_scale_is_rejected() -> None:
    t = fields(5)
    t["scales"][3, 1] = -1e-6
    with pytest.raises(ValueError, match=r"Gaussians\.scales must be >= 0.*1 Gaussians"):
        Gaussians(**t)


@pytest.mark.parametrize("value", [-1e-6, 1.0 + 1e-6, 2.0])
def test_opacity_outside_unit_interval_is_rejected(value: float) -> None:
    t = fields(5)
    t["opacities"][0] = value
    with pytest.raises(ValueError, match=r"Gaussians\.opacities must lie in \[0, 1\]"):
        Gaussians(**t)


def test_zero_quaternion_is_rejected() -> None:
    t = fields(5)
    t["quats"][4] = 0.0
    with pytest.raises(ValueError, match=r"Gaussians\.quats has zero-length"):
        Gaussians(**t)


@pytest.mark.parametrize(
    ("field", "shape"),
    [
        ("means", (5, 2)),
        ("quats", (5, 3)),
        ("quats", (4, 4)),
        ("scales", (6, 3)),
        ("scales", (5,)),
        ("opacities", (5, 1)),
        ("opacities", (4,)),
        ("sh", (4, 4, 3)),
        ("sh", (5, 4, 4)),
        ("sh", (5, 12)),
    ],
)
def test_shape_mismatch_is_rejected_naming_the_field(field: str, shape: tuple[int, ...]) -> None:
    t = fields(5)
    t[field] = torch.zeros(shape)
    with pytest.raises(ValueError, match=rf"Gaussians\.{field} must have shape"):
        Gaussians(**t)


def test_means_of_wrong_shape_are_named() -> None:
    t = fields(5)
    t["means"] = torch.zeros(5, 4)
    with pytest.raises(ValueError, match=r"Gaussians\.means must have shape \[5, 3\]"):
        Gaussians(**t)


@pytest.mark.parametrize("k", [0, 2, 3, 5, 8, 10, 25])
def test_sh_count_that_is_no_square_of_degree_0_to_3_is_rejected(k: int) -> None:
    t = fields(5)
    t["sh"] = torch.zeros(5, k, 3)
    with pytest.raises(ValueError, match=rf"Gaussians\.sh has K={k} coefficients"):
        Gaussians(**t)


@pytest.mark.parametrize("k", [1, 4, 9, 16])
def test_every_supported_sh_count_is_accepted(k: int) -> None:
    t = fields(5)
    t["sh"] = torch.zeros(5, k, 3)
    assert Gaussians(**t).sh_degree == math.isqrt(k) - 1


@pytest.mark.parametrize("field", FIELDS)
def test_non_tensor_field_is_rejected_naming_it(field: str) -> None:
    t = fields(5)
    t[field] = t[field].tolist()
    with pytest.raises(ValueError, match=rf"Gaussians\.{field}"):
        Gaussians(**t)


@pytest.mark.parametrize("field", FIELDS)
def test_integer_field_is_rejected_naming_it(field: str) -> None:
    t = fields(5)
    t[field] = t[field].round().to(torch.int64)
    if field == "quats":
        t[field][:, 0] = 1  # keep it non-zero so the dtype is what fails
    with pytest.raises(ValueError, match=rf"Gaussians\.{field} must be a floating-point"):
        Gaussians(**t)


def test_validate_catches_edits_made_after_construction() -> None:
    g = make()
    g.scales[1, 2] = -0.5
    with pytest.raises(ValueError, match=r"Gaussians\.scales"):
        g.validate()


# ---- moves ------------------------------------------------------------------------------
def test_to_float64_and_back_is_exact() -> None:
    g = make(7, degree=2)
    d = g.to(dtype=torch.float64)
    assert d.dtype == torch.float64
    for name in FIELDS:
        value = getattr(d, name)
        assert value.dtype == torch.float64, name
        assert torch.equal(value, getattr(g, name).double()), name
    assert_same(d.to(dtype=torch.float32), g)


def test_to_float16_rounds_each_field() -> None:
    g = make(7)
    h = g.to(dtype=torch.float16)
    for name in FIELDS:
        expected = getattr(g, name).half()
        assert torch.equal(getattr(h, name), expected), name


def test_to_cpu_keeps_values_and_reports_device() -> None:
    g = make()
    c = g.to(device="cpu")
    assert c.device == torch.device("cpu")
    assert_same(c, g)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_to_cuda_and_back() -> None:
    g = make(9, degree=3)
    c = g.to(device="cuda")
    assert c.device.type == "cuda"
    assert all(v.device.type == "cuda" for v in c.tensors().values())
    assert_same(c.to(device="cpu"), g)


def test_detach_drops_the_graph() -> None:
    t = {k: v.requires_grad_() for k, v in fields(3).items()}
    g = Gaussians(**t)
    d = g.detach()
    assert not any(v.requires_grad for v in d.tensors().values())
    assert all(v.requires_grad for v in g.tensors().values())


def test_tensors_lists_every_field_in_order() -> None:
    g = make()
    assert list(g.tensors()) == list(FIELDS)
    assert g.tensors()["sh"] is g.sh


# ---- cat ----------------------------------------------------------------------------------
def test_cat_pads_lower_sh_degrees_with_zeros() -> None:
    a, b, c = make(2, degree=0, seed=1), make(3, degree=2, seed=2), make(1, degree=1, seed=3)
    g = Gaussians.cat([a, b, c])
    assert len(g) == 6
    assert g.sh.shape == (6, 9, 3)
    assert g.sh_degree == 2
    assert torch.equal(g.sh[:2, :1], a.sh)
    assert torch.equal(g.sh[:2, 1:], torch.zeros(2, 8, 3))
    assert torch.equal(g.sh[2:5], b.sh)
    assert torch.equal(g.sh[5:, :4], c.sh)
    assert torch.equal(g.sh[5:, 4:], torch.zeros(1, 5, 3))
    for name in ("means", "quats", "scales", "opacities"):
        expected = torch.cat([getattr(a, name), getattr(b, name), getattr(c, name)])
        assert torch.equal(getattr(g, name), expected), name


def test_cat_of_nothing_is_an_error() -> None:
    with pytest.raises(ValueError, match="at least one"):
        Gaussians.cat([])


def test_cat_with_an_empty_set() -> None:
    g = make(4, degree=1)
    out = Gaussians.cat([Gaussians.empty(sh_degree=3), g])
    assert len(out) == 4 and out.sh_degree == 3
    assert torch.equal(out.sh[:, :4], g.sh)
    assert torch.equal(out.means, g.means)


# ---- subsets ------------------------------------------------------------------------------
def expected_subset(t: dict[str, torch.Tensor], rows: list[int]) -> dict[str, torch.Tensor]:
    """The rows picked one by one with Python indexing (the obvious twin of __getitem__)."""
    return {k: torch.stack([v[i] for i in rows]) if rows else v[:0] for k, v in t.items()}


def check_subset(g: Gaussians, t: dict[str, torch.Tensor], index, rows: list[int]) -> None:
    sub = g[index]
    expected = expected_subset(t, rows)
    assert len(sub) == len(rows)
    for name in FIELDS:
        assert torch.equal(getattr(sub, name), expected[name]), name


def test_subset_by_slice() -> None:
    t = fields(6, degree=2)
    g = Gaussians(**t)
    check_subset(g, t, slice(1, 4), [1, 2, 3])
    check_subset(g, t, slice(0, 6, 2), [0, 2, 4])
    check_subset(g, t, slice(5, 2), [])


def test_subset_by_mask() -> None:
    t = fields(6)
    g = Gaussians(**t)
    mask = torch.tensor([True, False, False, True, True, False])
    check_subset(g, t, mask, [0, 3, 4])
    check_subset(g, t, torch.zeros(6, dtype=torch.bool), [])


def test_subset_by_index_tensor_and_list_keeps_order_and_repeats() -> None:
    t = fields(6)
    g = Gaussians(**t)
    check_subset(g, t, torch.tensor([5, 0, 0, 2]), [5, 0, 0, 2])
    check_subset(g, t, [3, 1], [3, 1])


@pytest.mark.parametrize(("index", "row"), [(0, 0), (3, 3), (5, 5), (-1, 5), (-6, 0)])
def test_subset_by_int_keeps_the_leading_dimension(index: int, row: int) -> None:
    t = fields(6)
    check_subset(Gaussians(**t), t, index, [row])


def test_subset_by_zero_dim_tensor_is_one_gaussian() -> None:
    t = fields(6)
    check_subset(Gaussians(**t), t, torch.tensor(4), [4])


@pytest.mark.parametrize("index", [6, 100, -7])
def test_subset_int_out_of_range_raises(index: int) -> None:
    with pytest.raises(IndexError, match="out of range for 6"):
        make(6)[index]


# ---- empty set ----------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_empty_set(degree: int) -> None:
    g = Gaussians.empty(sh_degree=degree, dtype=torch.float64)
    assert len(g) == 0
    assert g.sh.shape == (0, (degree + 1) ** 2, 3)
    assert g.sh_degree == degree
    assert g.dtype == torch.float64
    g.validate()
    assert len(g[0:0]) == 0
    assert len(g[torch.zeros(0, dtype=torch.bool)]) == 0
    assert len(g.to(dtype=torch.float32)) == 0


# ---- colours ------------------------------------------------------------------------------
def test_sh_c0_is_the_degree_zero_harmonic() -> None:
    assert SH_C0 == pytest.approx(1.0 / (2.0 * math.sqrt(math.pi)), rel=1e-15)


def test_from_colors_stores_the_3dgs_dc_term_and_colours_round_trip() -> None:
    gen = torch.Generator().manual_seed(3)
    n = 10
    colors = torch.rand(n, 3, generator=gen, dtype=torch.float64)
    means = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    g = Gaussians.from_colors(means, colors, torch.ones(n, 3).double(), torch.ones(n).double())
    c0 = 1.0 / (2.0 * math.sqrt(math.pi))
    expected = [[(colors[i, c].item() - 0.5) / c0 for c in range(3)] for i in range(n)]
    assert torch.allclose(g.sh[:, 0], torch.tensor(expected, dtype=torch.float64), rtol=1e-12)
    assert torch.allclose(sh0_to_rgb(g.sh[:, 0]), colors, rtol=0, atol=1e-12)
    assert torch.equal(g.quats, torch.tensor([[1.0, 0, 0, 0]] * n, dtype=torch.float64))
    assert g.sh_degree == 0


def test_from_colors_with_higher_degree_and_given_quats() -> None:
    n = 4
    colors = torch.tensor([[0.0, 0.5, 1.0], [1.0, 1.0, 1.0], [0.25, 0.0, 0.75], [0.5, 0.5, 0.5]])
    quats = torch.tensor([[0.0, 1.0, 0.0, 0.0]] * n)
    g = Gaussians.from_colors(
        torch.zeros(n, 3), colors, torch.ones(n, 3), torch.ones(n), quats=quats, sh_degree=2
    )
    assert g.sh.shape == (n, 9, 3)
    assert torch.equal(g.sh[:, 1:], torch.zeros(n, 8, 3))
    assert torch.equal(g.quats, quats)
    assert torch.allclose(sh0_to_rgb(g.sh[:, 0]), colors, atol=1e-6)
    assert torch.equal(g.sh[3, 0], torch.zeros(3))  # mid grey is a zero DC term
    assert g.sh[1, 0, 0].item() == pytest.approx(0.5 * 2.0 * math.sqrt(math.pi), rel=1e-6)


def test_rgb_to_sh0_inverts_sh0_to_rgb() -> None:
    sh0 = torch.linspace(-3, 3, 13, dtype=torch.float64).reshape(-1, 1).expand(-1, 3)
    assert torch.allclose(rgb_to_sh0(sh0_to_rgb(sh0)), sh0, atol=1e-12)


# ---- sh degree ----------------------------------------------------------------------------
def test_with_sh_degree_truncates_and_pads() -> None:
    g = make(3, degree=2)
    low = g.with_sh_degree(1)
    assert torch.equal(low.sh, g.sh[:, :4])
    high = g.with_sh_degree(3)
    assert torch.equal(high.sh[:, :9], g.sh)
    assert torch.equal(high.sh[:, 9:], torch.zeros(3, 7, 3))
    assert torch.equal(high.means, g.means)
