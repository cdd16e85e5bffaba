"""Tests for the 3DGS PLY reader/writer (``prosplat.core.ply``).

Files "from other tools" are written here by hand with plyfile, following those tools'
layouts, and expected values are computed independently with ``math`` / numpy float64.
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

import prosplat.core.ply as ply_module
from prosplat import Gaussians, read_ply, write_ply

ULP = 2.0**-24  # half the float32 spacing just below 1, relative


def random_gaussians(n: int, degree: int, seed: int = 0) -> Gaussians:
    """Float32 Gaussians with values spread over typical ranges (scales 3e-4 .. 20)."""
    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        means=torch.randn(n, 3, generator=gen) * 10,
        quats=torch.randn(n, 4, generator=gen) * 3,  # not normalised: must come back as is
        scales=torch.exp(torch.rand(n, 3, generator=gen) * 11 - 8),
        opacities=torch.rand(n, generator=gen),
        sh=torch.randn(n, k, 3, generator=gen),
    )


def inria_attributes(k: int) -> list[str]:
    """INRIA 3DGS ``GaussianModel.construct_list_of_attributes`` (K coefficients/channel)."""
    names = ["x", "y", "z", "nx", "ny", "nz"]
    names += [f"f_dc_{i}" for i in range(3)]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names.append("opacity")
    names += [f"scale_{i}" for i in range(3)]
    names += [f"rot_{i}" for i in range(4)]
    return names


def write_columns(
    path: Path,
    columns: dict[str, np.ndarray],
    types: dict[str, str] | None = None,
    text: bool = False,
    byte_order: str = "<",
) -> None:
    """A one-element PLY whose vertex properties are ``columns`` in the given order."""
    types = types or {}
    n = len(next(iter(columns.values())))
    dtype = [(name, types.get(name, "f4")) for name in columns]
    data = np.empty(n, dtype=dtype)
    for name, values in columns.items():
        data[name] = values
    PlyData([PlyElement.describe(data, "vertex")], text=text, byte_order=byte_order).write(
        str(path)
    )


def logit(p: float) -> float:
    return math.log(p / (1.0 - p))


def sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


def known_columns(n: int = 4, degree: int = 1) -> dict[str, np.ndarray]:
    """Columns of a valid file with simple, hand-chosen values."""
    k = (degree + 1) ** 2
    cols: dict[str, np.ndarray] = {
        "x": np.arange(n) + 0.5,
        "y": -np.arange(n) * 2.0,
        "z": np.full(n, 3.0),
        "f_dc_0": np.full(n, 0.1),
        "f_dc_1": np.full(n, 0.2),
        "f_dc_2": np.full(n, 0.3),
    }
    for i in range(3 * (k - 1)):
        cols[f"f_rest_{i}"] = np.full(n, i + 0.5)
    cols["opacity"] = np.zeros(n)
    for i in range(3):
        cols[f"scale_{i}"] = np.full(n, -float(i))
    cols.update(rot_0=np.ones(n), rot_1=np.zeros(n), rot_2=np.zeros(n), rot_3=np.zeros(n))
    return cols


def assert_same(a: Gaussians, b: Gaussians) -> None:
    for name in ("means", "quats", "scales", "opacities", "sh"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert torch.equal(x, y), name


# ---- round trip ---------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("binary", [True, False])
def test_round_trip(tmp_path: Path, degree: int, binary: bool) -> None:
    g = random_gaussians(300, degree, seed=degree)
    path = tmp_path / "g.ply"
    write_ply(g, path, binary=binary)
    h = read_ply(path)
    assert h.sh_degree == degree and len(h) == 300
    # Copied as float32: bit for bit.
    for name in ("means", "quats", "sh"):
        assert torch.equal(getattr(h, name), getattr(g, name)), name
    # Stored as logit / log: exact where float32 codes can be, else within the stated bound.
    o, o2 = g.opacities.double(), h.opacities.double()
    bound = (torch.log(o / (1 - o)).abs() * (1 - o) + 1) * ULP * 1.01
    assert ((o2 - o).abs() <= bound * o).all()
    exact_o = o >= 0.25
    assert torch.equal(h.opacities[exact_o], g.opacities[exact_o])
    s, s2 = g.scales.double(), h.scales.double()
    assert ((s2 - s).abs() <= (s.log().abs() + 1) * ULP * 1.01 * s).all()
    exact_s = (s > math.exp(-1)) & (s < math.exp(1))
    assert exact_s.sum() > 50  # the sample does reach the exact band
    assert torch.equal(h.scales[exact_s], g.scales[exact_s])


@pytest.mark.parametrize("degree", [0, 3])
def test_round_trip_of_empty_set(tmp_path: Path, degree: int) -> None:
    path = tmp_path / "empty.ply"
    write_ply(Gaussians.empty(sh_degree=degree), path)
    h = read_ply(path, allow_empty=True)  # refused by default: test_ply_warnings.py
    assert len(h) == 0 and h.sh_degree == degree


def random_float32_between(lo: float, hi: float, n: int, seed: int) -> torch.Tensor:
    """``n`` float32 values drawn uniformly over the *bit patterns* in [lo, hi), so every
    binade is sampled, not just the top one."""
    a, b = np.array([lo, hi], dtype=np.float32).view(np.int32)
    bits = np.random.default_rng(seed).integers(a, b, n, dtype=np.int32)
    return torch.from_numpy(bits.view(np.float32).copy())


def test_opacities_in_the_exact_band_round_trip_bit_for_bit(tmp_path: Path) -> None:
    n = 200_000
    opacities = random_float32_between(0.25, 1.0, n, seed=1)
    opacities[:2] = torch.tensor([0.25, 1.0 - 2.0**-24])  # the band's ends
    g = Gaussians.from_colors(torch.zeros(n, 3), torch.zeros(n, 3), torch.ones(n, 3), opacities)
    write_ply(g, tmp_path / "o.ply")
    assert torch.equal(read_ply(tmp_path / "o.ply").opacities, opacities)


def test_scales_in_the_exact_band_round_trip_bit_for_bit(tmp_path: Path) -> None:
    n = 200_000
    lo, hi = np.nextafter(np.float32(math.exp(-1)), np.float32(1)), np.float32(math.exp(1))
    scales = random_float32_between(float(lo), float(hi), 3 * n, seed=2).reshape(n, 3)
    g = Gaussians.from_colors(torch.zeros(n, 3), torch.zeros(n, 3), scales, torch.ones(n))
    write_ply(g, tmp_path / "s.ply")
    assert torch.equal(read_ply(tmp_path / "s.ply").scales, scales)


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.floats(0.0, 1.0, width=32), min_size=1, max_size=20),
    st.lists(st.floats(0.0, 1e6, width=32), min_size=3, max_size=3),
)
def test_any_float32_opacity_and_scale_survive_within_the_bound(
    tmp_path_factory: pytest.TempPathFactory, opacities: list[float], scale: list[float]
) -> None:
    n = len(opacities)
    o = torch.tensor(opacities, dtype=torch.float32)
    s = torch.tensor([scale] * n, dtype=torch.float32)
    path = tmp_path_factory.mktemp("h") / "h.ply"
    write_ply(Gaussians.from_colors(torch.zeros(n, 3), torch.zeros(n, 3), s, o), path)
    h = read_ply(path)
    for before, after in zip(o.tolist(), h.opacities.tolist(), strict=True):
        if before < 1.2e-38:  # below the clamp: comes back as the clamp
            assert 0 < after < 1.2e-38
        elif before >= 0.25:
            assert after == before
        else:
            err = (abs(logit(before)) * (1 - before) + 1) * ULP * 1.01
            assert abs(after - before) <= err * before
    for before, after in zip(s[0].tolist(), h.scales[0].tolist(), strict=True):
        if before < 1.2e-38:
            assert 0 < after < 1.2e-38
        else:
            assert abs(after - before) <= (abs(math.log(before)) + 1) * ULP * 1.01 * before


def test_edge_values_give_finite_codes_and_decode_sensibly(tmp_path: Path) -> None:
    opacities = torch.tensor([0.0, 1.0, 1e-45, 0.5])
    scales = torch.tensor([[0.0, 1e-40, 1e30]] * 4)
    g = Gaussians.from_colors(torch.zeros(4, 3), torch.zeros(4, 3), scales, opacities)
    path = tmp_path / "edge.ply"
    write_ply(g, path)
    raw = PlyData.read(str(path))["vertex"].data
    for name in ("opacity", "scale_0", "scale_1", "scale_2"):
        assert np.isfinite(raw[name]).all(), name
    assert raw["opacity"][0] == pytest.approx(math.log(2.0**-126), rel=1e-6)  # OPACITY_MIN
    assert raw["scale_0"][0] == pytest.approx(math.log(2.0**-126), rel=1e-6)  # SCALE_MIN
    h = read_ply(path)
    assert h.opacities[1].item() == 1.0  # opacity 1 survives exactly
    assert h.opacities[3].item() == 0.5
    assert 0 < h.opacities[0].item() < 1.2e-38 and 0 < h.opacities[2].item() < 1.2e-38
    assert 0 < h.scales[0, 0].item() < 1.2e-38 and 0 < h.scales[0, 1].item() < 1.2e-38
    assert h.scales[0, 2].item() == pytest.approx(1e30, rel=1e-5)


def test_float64_gaussians_are_written_as_float32(tmp_path: Path) -> None:
    g = random_gaussians(50, 1).to(dtype=torch.float64)
    g.means += 1e-12  # not representable in float32
    write_ply(g, tmp_path / "d.ply")
    h = read_ply(tmp_path / "d.ply", dtype=torch.float64)
    assert torch.equal(h.means, g.means.float().double())
    assert torch.equal(h.sh, g.sh.float().double())


# ---- layout -------------------------------------------------------------------------------
@pytest.mark.parametrize("degree", [0, 2, 3])
def test_written_file_has_inrias_exact_layout(tmp_path: Path, degree: int) -> None:
    g = random_gaussians(20, degree)
    k = (degree + 1) ** 2
    path = tmp_path / "layout.ply"
    write_ply(g, path)
    header = path.read_bytes().split(b"end_header\n")[0].decode()
    expected_header = "\n".join(
        ["ply", "format binary_little_endian 1.0", "element vertex 20"]
        + [f"property float {name}" for name in inria_attributes(k)]
    )
    assert header.strip() == expected_header
    raw = PlyData.read(str(path))["vertex"].data
    for name in ("nx", "ny", "nz"):
        assert (raw[name] == 0).all()
    for i, name in enumerate(("x", "y", "z")):
        assert np.array_equal(raw[name], g.means[:, i].numpy())
    for c in range(3):
        assert np.array_equal(raw[f"f_dc_{c}"], g.sh[:, 0, c].numpy())
    for i in range(3 * (k - 1)):  # channel-major: f_rest_i = sh[1 + i % (K-1), i // (K-1)]
        assert np.array_equal(raw[f"f_rest_{i}"], g.sh[:, 1 + i % (k - 1), i // (k - 1)].numpy())
    for n in range(20):
        o = float(g.opacities[n])
        assert raw["opacity"][n] == pytest.approx(logit(o), rel=1e-6, abs=1e-6)
        for i in range(3):
            assert raw[f"scale_{i}"][n] == pytest.approx(math.log(float(g.scales[n, i])), rel=1e-6)
        for i in range(4):
            assert raw[f"rot_{i}"][n] == g.quats[n, i].item()


def test_ascii_file_says_so(tmp_path: Path) -> None:
    write_ply(random_gaussians(3, 0), tmp_path / "a.ply", binary=False)
    assert path_header(tmp_path / "a.ply").startswith("ply\nformat ascii 1.0\n")


def path_header(path: Path) -> str:
    return path.read_bytes().split(b"end_header")[0].decode()


# ---- files from other tools ---------------------------------------------------------------
def write_like_inria(path: Path, xyz, features_dc, features_rest, opacity, scale, rotation):
    """INRIA 3DGS ``GaussianModel.save_ply``, transcribed (torch tensors in, PLY out)."""
    normals = np.zeros_like(xyz)
    f_dc = features_dc.transpose(1, 2).flatten(start_dim=1).contiguous().numpy()
    f_rest = features_rest.transpose(1, 2).flatten(start_dim=1).contiguous().numpy()
    k = features_rest.shape[1] + 1
    dtype_full = [(attribute, "f4") for attribute in inria_attributes(k)]
    elements = np.empty(xyz.shape[0], dtype=dtype_full)
    attributes = np.concatenate(
        (xyz, normals, f_dc, f_rest, opacity.numpy(), scale.numpy(), rotation.numpy()), axis=1
    )
    elements[:] = list(map(tuple, attributes))
    PlyData([PlyElement.describe(elements, "vertex")]).write(str(path))


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_reads_a_file_in_inrias_layout(tmp_path: Path, degree: int) -> None:
    gen = torch.Generator().manual_seed(7)
    n, k = 30, (degree + 1) ** 2
    xyz = torch.randn(n, 3, generator=gen).numpy()
    features_dc = torch.randn(n, 1, 3, generator=gen)  # INRIA's [N, 1, 3]
    features_rest = torch.randn(n, k - 1, 3, generator=gen)  # INRIA's [N, K-1, 3]
    opacity = torch.randn(n, 1, generator=gen) * 3  # logits
    scale = torch.randn(n, 3, generator=gen) - 4  # log scales
    rotation = torch.randn(n, 4, generator=gen)
    path = tmp_path / "point_cloud.ply"
    write_like_inria(path, xyz, features_dc, features_rest, opacity, scale, rotation)

    g = read_ply(path)
    assert g.sh_degree == degree
    assert torch.equal(g.means, torch.from_numpy(xyz))
    assert torch.equal(g.sh[:, :1], features_dc)
    assert torch.equal(g.sh[:, 1:], features_rest)
    assert torch.equal(g.quats, rotation)
    expected_o = [sigmoid(v) for v in opacity[:, 0].tolist()]
    assert g.opacities.tolist() == pytest.approx(expected_o, rel=2e-7)
    expected_s = [[math.exp(v) for v in row] for row in scale.tolist()]
    assert np.allclose(g.scales.numpy(), np.array(expected_s), rtol=2e-7, atol=0)


def test_our_file_read_back_the_inria_way(tmp_path: Path) -> None:
    """What INRIA's ``load_ply`` reconstructs from our file equals our Gaussians."""
    g = random_gaussians(25, 3)
    path = tmp_path / "ours.ply"
    write_ply(g, path)
    el = PlyData.read(str(path)).elements[0]
    extra = sorted(
        (p.name for p in el.properties if p.name.startswith("f_rest_")),
        key=lambda x: int(x.split("_")[-1]),
    )
    features_extra = np.zeros((25, len(extra)))
    for idx, attr_name in enumerate(extra):
        features_extra[:, idx] = np.asarray(el[attr_name])
    features_extra = features_extra.reshape((25, 3, 15))  # INRIA: (P, 3, (deg+1)^2 - 1)
    rest = torch.tensor(features_extra, dtype=torch.float32).transpose(1, 2)
    assert torch.equal(rest, g.sh[:, 1:])
    opacity = torch.sigmoid(torch.tensor(np.asarray(el["opacity"]), dtype=torch.float64))
    assert torch.allclose(opacity.float(), g.opacities, rtol=1e-6, atol=0)


def test_shuffled_order_and_extra_properties(tmp_path: Path) -> None:
    cols = known_columns(5, degree=1)
    reference = tmp_path / "plain.ply"
    write_columns(reference, cols)
    extra = {"red": np.arange(5), "segment": -np.arange(5), "confidence": np.linspace(0, 1, 5)}
    extra |= {"nx": np.ones(5), "ny": np.ones(5), "nz": np.ones(5)}
    everything = cols | extra
    names = list(everything)
    np.random.default_rng(0).shuffle(names)
    shuffled = tmp_path / "shuffled.ply"
    types = {"red": "u1", "segment": "i4", "confidence": "f8"}
    write_columns(shuffled, {name: everything[name] for name in names}, types)
    with pytest.warns(ply_module.PlyWarning, match="confidence, red, segment"):
        assert_same(read_ply(shuffled), read_ply(reference))


def test_shuffled_float32_only_file_uses_the_same_columns(tmp_path: Path) -> None:
    """All-float32 files take the fast gather path; shuffling must not confuse it."""
    g = random_gaussians(40, 2)
    ours = tmp_path / "ours.ply"
    write_ply(g, ours)
    raw = PlyData.read(str(ours))["vertex"].data
    names = list(raw.dtype.names)[::-1]
    write_columns(tmp_path / "rev.ply", {name: raw[name] for name in names})
    assert_same(read_ply(tmp_path / "rev.ply"), read_ply(ours))


@pytest.mark.parametrize(
    ("text", "byte_order"), [(False, ">"), (True, "="), (False, "<")], ids=["be", "ascii", "le"]
)
def test_encodings(tmp_path: Path, text: bool, byte_order: str) -> None:
    g = random_gaussians(40, 1)
    ours = tmp_path / "ours.ply"
    write_ply(g, ours)
    raw = PlyData.read(str(ours))["vertex"].data
    other = tmp_path / "other.ply"
    write_columns(other, {n: raw[n] for n in raw.dtype.names}, text=text, byte_order=byte_order)
    expected = {False: {">": "binary_big_endian", "<": "binary_little_endian"}, True: {}}
    assert f"format {expected[text].get(byte_order, 'ascii')} 1.0" in path_header(other)
    assert_same(read_ply(other), read_ply(ours))


def test_float64_file(tmp_path: Path) -> None:
    cols = known_columns(3, degree=1)
    cols["x"] = np.array([0.1, 1e-300, 1 / 3])  # float64 values float32 cannot hold exactly
    cols["opacity"] = np.array([0.3, -1.7, 4.1])
    cols["scale_0"] = np.array([-2.2, 0.7, 1.3])
    path = tmp_path / "f8.ply"
    write_columns(path, cols, {name: "f8" for name in cols})
    g64 = read_ply(path, dtype=torch.float64)
    assert g64.means[:, 0].tolist() == [0.1, 1e-300, 1 / 3]
    assert g64.opacities.tolist() == pytest.approx([sigmoid(0.3), sigmoid(-1.7), sigmoid(4.1)])
    assert g64.scales[:, 0].tolist() == pytest.approx([math.exp(-2.2), math.exp(0.7), 3.6693])
    g32 = read_ply(path)
    assert g32.dtype == torch.float32
    assert torch.equal(g32.means[:, 0], torch.tensor([0.1, 1e-300, 1 / 3]).float())
    # decoded in float64 from the float64 logit, then rounded once
    assert torch.equal(g32.opacities, g64.opacities.float())


def test_integer_property_types(tmp_path: Path) -> None:
    cols = known_columns(3, degree=0)
    cols["x"] = np.array([-3, 0, 70])
    cols["opacity"] = np.array([0, 1, -1])
    cols["scale_1"] = np.array([0, 2, -2])
    cols["rot_0"] = np.array([1, 2, 0])  # 0 with zero x y z: a zero quaternion
    types = {"x": "i2", "opacity": "i1", "scale_1": "i4", "rot_0": "u2", "f_dc_0": "f8"}
    write_columns(tmp_path / "i.ply", cols, types)
    g = read_ply(tmp_path / "i.ply")
    assert g.means[:, 0].tolist() == [-3.0, 0.0, 70.0]
    assert g.opacities.tolist() == pytest.approx([0.5, sigmoid(1), sigmoid(-1)], rel=1e-7)
    assert g.scales[:, 1].tolist() == pytest.approx([1.0, math.exp(2), math.exp(-2)], rel=1e-7)
    assert g.quats.tolist() == [[1, 0, 0, 0], [2, 0, 0, 0], [1, 0, 0, 0]]


def test_file_without_f_rest_is_degree_0(tmp_path: Path) -> None:
    write_columns(tmp_path / "d0.ply", known_columns(4, degree=0))
    g = read_ply(tmp_path / "d0.ply")
    assert g.sh.shape == (4, 1, 3)
    assert g.sh[:, 0].tolist() == [pytest.approx([0.1, 0.2, 0.3])] * 4


def test_known_values_are_decoded(tmp_path: Path) -> None:
    cols = known_columns(4, degree=1)
    cols["opacity"] = np.array([0.0, math.log(3.0), -math.log(9.0), 20.0])
    cols["scale_0"] = np.array([0.0, math.log(0.01), math.log(2.0), -10.0])
    cols["rot_1"] = np.array([0.0, 0.5, 0.0, 0.0])
    cols["f_dc_1"] = np.array([0.0, 1.0, -1.0, 0.5])
    write_columns(tmp_path / "k.ply", cols)
    g = read_ply(tmp_path / "k.ply")
    assert g.opacities.tolist() == pytest.approx([0.5, 0.75, 0.1, 1 / (1 + math.exp(-20))])
    assert g.scales[:, 0].tolist() == pytest.approx([1.0, 0.01, 2.0, math.exp(-10)], rel=1e-6)
    assert g.scales[:, 1].tolist() == pytest.approx([math.exp(-1)] * 4, rel=1e-6)
    assert g.scales[:, 2].tolist() == pytest.approx([math.exp(-2)] * 4, rel=1e-6)
    assert g.quats[1].tolist() == [1.0, 0.5, 0.0, 0.0]  # as stored, not normalised
    # f_rest_i holds i + 0.5 and is channel-major: sh[:, j, c] = f_rest_{3c + j - 1}
    for j in range(1, 4):
        for c in range(3):
            assert (g.sh[:, j, c] == 3 * c + (j - 1) + 0.5).all(), (j, c)
    assert g.sh[:, 0, 1].tolist() == [0.0, 1.0, -1.0, 0.5]
    assert g.means[:, 0].tolist() == [0.5, 1.5, 2.5, 3.5]


def test_zero_quaternion_becomes_identity(tmp_path: Path) -> None:
    cols = known_columns(3, degree=0)
    cols["rot_0"] = np.array([0.0, 0.0, -2.0])
    cols["rot_3"] = np.array([0.0, 1e-3, 0.0])
    write_columns(tmp_path / "q.ply", cols)
    q = read_ply(tmp_path / "q.ply").quats.tolist()
    assert q == [[1, 0, 0, 0], [0, 0, 0, pytest.approx(1e-3)], [-2, 0, 0, 0]]


def test_read_dtype_and_device(tmp_path: Path) -> None:
    g = random_gaussians(10, 1)
    write_ply(g, tmp_path / "g.ply")
    h = read_ply(tmp_path / "g.ply", device="cpu", dtype=torch.float64)
    assert h.dtype == torch.float64 and h.device == torch.device("cpu")
    assert torch.equal(h.means, g.means.double())
    assert torch.equal(h.sh, g.sh.double())
    raw = PlyData.read(str(tmp_path / "g.ply"))["vertex"].data
    expected = [sigmoid(float(v)) for v in raw["opacity"]]
    assert h.opacities.tolist() == pytest.approx(expected, rel=1e-14)
    half = read_ply(tmp_path / "g.ply", dtype=torch.float16)
    assert half.dtype == torch.float16
    assert torch.equal(half.means, h.means.half())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_read_to_cuda(tmp_path: Path) -> None:
    g = random_gaussians(10, 2)
    write_ply(g, tmp_path / "g.ply")
    h = read_ply(tmp_path / "g.ply", device="cuda")
    assert h.device.type == "cuda"
    assert torch.equal(h.sh.cpu(), g.sh)


# ---- read errors --------------------------------------------------------------------------
def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nothere.ply"):
        read_ply(tmp_path / "nothere.ply")


@pytest.mark.parametrize("name", ["x", "z", "f_dc_1", "opacity", "scale_2", "rot_0", "rot_3"])
def test_missing_required_property(tmp_path: Path, name: str) -> None:
    cols = known_columns(2, degree=1)
    del cols[name]
    write_columns(tmp_path / "m.ply", cols)
    with pytest.raises(ValueError, match=rf"m\.ply has no vertex property '{name}'"):
        read_ply(tmp_path / "m.ply")


@pytest.mark.parametrize("count", [1, 3, 8, 10, 15, 44, 46])
def test_unsupported_f_rest_count(tmp_path: Path, count: int) -> None:
    cols = known_columns(2, degree=0)
    cols |= {f"f_rest_{i}": np.zeros(2) for i in range(count)}
    write_columns(tmp_path / "r.ply", cols)
    with pytest.raises(ValueError, match=rf"has {count} f_rest_\* properties"):
        read_ply(tmp_path / "r.ply")


def test_gap_in_f_rest_names_the_missing_one(tmp_path: Path) -> None:
    cols = known_columns(2, degree=1)
    cols["f_rest_9"] = cols.pop("f_rest_8")
    write_columns(tmp_path / "gap.ply", cols)
    with pytest.raises(ValueError, match="no vertex property 'f_rest_8'"):
        read_ply(tmp_path / "gap.ply")


@pytest.mark.parametrize(
    ("name", "value"),
    [("x", math.nan), ("f_rest_4", -math.inf), ("opacity", math.inf), ("scale_1", math.nan)]
    + [("opacity", -math.inf), ("scale_0", -math.inf), ("rot_2", math.nan)],
)
def test_non_finite_value_names_property_and_file(tmp_path: Path, name: str, value: float):
    cols = known_columns(3, degree=1)
    cols[name][1] = value
    write_columns(tmp_path / "nan.ply", cols)
    with pytest.raises(ValueError, match=rf"nan\.ply: property '{name}' has 1 NaN or Inf"):
        read_ply(tmp_path / "nan.ply")


def test_values_too_large_for_float32(tmp_path: Path) -> None:
    cols = known_columns(2, degree=0)
    cols["y"][0] = 1e300
    write_columns(tmp_path / "big.ply", cols, {name: "f8" for name in cols})
    with pytest.raises(ValueError, match=r"big\.ply: property 'y' gives values too large"):
        read_ply(tmp_path / "big.ply")
    assert read_ply(tmp_path / "big.ply", dtype=torch.float64).means[0, 1].item() == 1e300


def test_log_scale_too_large_for_float32(tmp_path: Path) -> None:
    cols = known_columns(2, degree=0)
    cols["scale_2"][1] = 100.0  # exp(100) = 2.7e43 > float32 max
    write_columns(tmp_path / "s.ply", cols)
    with pytest.raises(ValueError, match="property 'scale_2' gives values too large"):
        read_ply(tmp_path / "s.ply")


@pytest.mark.parametrize(
    "content",
    [b"", b"hello\n", bytes(range(256)), b"ply\nformat ascii 1.0\nelement vertex 2\n"],
    ids=["empty", "text", "binary", "no-end-header"],
)
def test_not_a_ply(tmp_path: Path, content: bytes) -> None:
    (tmp_path / "bad.ply").write_bytes(content)
    with pytest.raises(ValueError, match=r"bad\.ply is not a readable PLY"):
        read_ply(tmp_path / "bad.ply")


def test_truncated_binary_file(tmp_path: Path) -> None:
    write_ply(random_gaussians(100, 1), tmp_path / "t.ply")
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[: len(data) - 50])
    with pytest.raises(ValueError, match=r"t\.ply is not a readable PLY.*end-of-file"):
        read_ply(tmp_path / "t.ply")


def test_no_vertex_element(tmp_path: Path) -> None:
    data = np.zeros(2, dtype=[("x", "f4")])
    PlyData([PlyElement.describe(data, "points")]).write(str(tmp_path / "p.ply"))
    with pytest.raises(ValueError, match=r"no 'vertex' element \(it has \['points'\]\)"):
        read_ply(tmp_path / "p.ply")


def test_compressed_ply_gets_a_hint(tmp_path: Path) -> None:
    chunk = np.zeros(1, dtype=[("min_x", "f4")])
    vertex = np.zeros(2, dtype=[("packed_position", "u4"), ("packed_rotation", "u4")])
    elements = [PlyElement.describe(chunk, "chunk"), PlyElement.describe(vertex, "vertex")]
    PlyData(elements).write(str(tmp_path / "c.ply"))
    with pytest.raises(ValueError, match="compressed PLY"):
        read_ply(tmp_path / "c.ply")


def test_list_property_where_a_scalar_is_needed(tmp_path: Path) -> None:
    cols = known_columns(2, degree=0)
    del cols["opacity"]
    dtype = [(name, "f4") for name in cols] + [("opacity", "O")]
    data = np.empty(2, dtype=dtype)
    for name, values in cols.items():
        data[name] = values
    data["opacity"] = [np.array([0.0], "f4"), np.array([1.0], "f4")]
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "l.ply"))
    with pytest.raises(ValueError, match="'opacity' is a list"):
        read_ply(tmp_path / "l.ply")


def test_non_float_dtype_is_refused(tmp_path: Path) -> None:
    write_ply(random_gaussians(2, 0), tmp_path / "g.ply")
    with pytest.raises(ValueError, match="floating-point dtype"):
        read_ply(tmp_path / "g.ply", dtype=torch.int32)


# ---- write errors and safety --------------------------------------------------------------
def test_missing_folder_is_not_created(tmp_path: Path) -> None:
    target = tmp_path / "no" / "such" / "g.ply"
    with pytest.raises(FileNotFoundError, match=r"folder .*such does not exist"):
        write_ply(random_gaussians(2, 0), target)
    assert not (tmp_path / "no").exists()


def test_existing_file_is_not_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "mine.ply"
    path.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_ply(random_gaussians(2, 0), path)
    assert path.read_bytes() == b"precious"
    assert os.listdir(tmp_path) == ["mine.ply"]


def test_overwrite_replaces(tmp_path: Path) -> None:
    path = tmp_path / "g.ply"
    write_ply(random_gaussians(2, 0, seed=1), path)
    g = random_gaussians(3, 1, seed=2)
    write_ply(g, path, overwrite=True)
    assert torch.equal(read_ply(path).means, g.means)
    assert os.listdir(tmp_path) == ["g.ply"]


def test_folder_as_target(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    with pytest.raises(IsADirectoryError):
        write_ply(random_gaussians(2, 0), tmp_path / "d", overwrite=True)


def test_invalid_gaussians_are_not_written(tmp_path: Path) -> None:
    g = random_gaussians(3, 0)
    g.means[1, 1] = math.nan  # edited after construction
    with pytest.raises(ValueError, match=r"Gaussians\.means"):
        write_ply(g, tmp_path / "g.ply")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("existing", [False, True])
def test_interrupted_write_leaves_no_half_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, existing: bool
) -> None:
    path = tmp_path / "g.ply"
    if existing:
        path.write_bytes(b"old")

    def broken_write(self, stream) -> None:
        stream.write(b"ply\nformat binary_little_endian 1.0\n")  # half a file, then...
        raise KeyboardInterrupt

    monkeypatch.setattr(ply_module.PlyData, "write", broken_write)
    with pytest.raises(KeyboardInterrupt):
        write_ply(random_gaussians(5, 0), path, overwrite=True)
    if existing:
        assert path.read_bytes() == b"old"
        assert os.listdir(tmp_path) == ["g.ply"]
    else:
        assert os.listdir(tmp_path) == []


def test_file_appearing_during_the_write_is_not_overwritten(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The existence check happens before the (slow) write; the final move must not clobber
    a file that another program created in the meantime."""
    path = tmp_path / "g.ply"
    real_write = ply_module.PlyData.write

    def racing_write(self, stream) -> None:
        path.write_bytes(b"theirs")
        real_write(self, stream)

    monkeypatch.setattr(ply_module.PlyData, "write", racing_write)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_ply(random_gaussians(5, 0), path)
    assert path.read_bytes() == b"theirs"
    assert os.listdir(tmp_path) == ["g.ply"]


def test_writes_through_a_string_path_in_the_current_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    write_ply(random_gaussians(2, 0), "here.ply")
    assert len(read_ply("here.ply")) == 2


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permissions")
def test_new_file_gets_the_usual_permissions(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        write_ply(random_gaussians(2, 0), tmp_path / "g.ply")
    finally:
        os.umask(old)
    assert (tmp_path / "g.ply").stat().st_mode & 0o777 == 0o644


# ---- speed --------------------------------------------------------------------------------
def test_large_file_has_no_per_vertex_loop(tmp_path: Path) -> None:
    """200k degree-3 Gaussians (50 MB): a per-vertex Python loop would take minutes."""
    g = random_gaussians(200_000, 3)
    start = time.perf_counter()
    write_ply(g, tmp_path / "big.ply")
    h = read_ply(tmp_path / "big.ply")
    assert time.perf_counter() - start < 20
    assert torch.equal(h.sh, g.sh)


@pytest.mark.slow
def test_million_gaussians_in_a_few_seconds(tmp_path: Path) -> None:
    g = random_gaussians(1_000_000, 3)
    start = time.perf_counter()
    write_ply(g, tmp_path / "big.ply")
    h = read_ply(tmp_path / "big.ply")
    assert time.perf_counter() - start < 10
    assert torch.equal(h.means, g.means)
