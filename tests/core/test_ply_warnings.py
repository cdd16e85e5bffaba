"""``read_ply`` tells what it drops and refuses files with no Gaussians (issue 15).

Splat editors add their own data to the 3DGS PLY (SuperSplat a ``transform`` element, others
per-splat flags); the reader keeps the Gaussians and names the rest in one warning, which the
add-on's import reports. A 0-point file is refused rather than imported as an empty object.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement
from test_ply import known_columns, random_gaussians, write_columns

from prosplat import Gaussians, read_ply, write_ply
from prosplat.core.ply import PlyWarning


def test_own_and_inria_files_read_without_warnings(tmp_path: Path) -> None:
    write_ply(random_gaussians(5, 1), tmp_path / "ours.ply")  # has nx ny nz, as INRIA's
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(read_ply(tmp_path / "ours.ply")) == 5


def test_unknown_vertex_properties_are_named(tmp_path: Path) -> None:
    cols = known_columns(4, degree=1) | {"selection": np.ones(4), "red": np.arange(4)}
    write_columns(tmp_path / "extra.ply", cols, {"selection": "u1", "red": "u1"})
    with pytest.warns(PlyWarning, match=r"extra\.ply: dropped vertex properties selection, red"):
        g = read_ply(tmp_path / "extra.ply")
    assert len(g) == 4


def test_supersplat_transform_element_is_named_through_the_callback(tmp_path: Path) -> None:
    """SuperSplat writes its scene transform beside the vertices; it is not applied here."""
    vertex = np.empty(3, dtype=[(name, "f4") for name in known_columns(3, degree=0)])
    for name, values in known_columns(3, degree=0).items():
        vertex[name] = values
    transform = np.zeros(1, dtype=[("transform", "f4")])
    ply = PlyData([PlyElement.describe(vertex, "vertex"),
                   PlyElement.describe(transform, "transform")])  # fmt: skip
    ply.write(str(tmp_path / "super.ply"))
    seen: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # with a callback, nothing goes to warnings
        g = read_ply(tmp_path / "super.ply", on_warning=seen.append)
    assert len(g) == 3
    assert seen == ["super.ply: dropped elements transform (not part of a 3DGS Gaussian)"]


def test_long_lists_of_dropped_properties_are_shortened(tmp_path: Path) -> None:
    extra = {f"custom_{i}": np.zeros(2) for i in range(11)}
    write_columns(tmp_path / "many.ply", known_columns(2, degree=0) | extra)
    seen: list[str] = []
    read_ply(tmp_path / "many.ply", on_warning=seen.append)
    assert len(seen) == 1 and "custom_7 and 3 more" in seen[0] and "custom_8" not in seen[0]


@pytest.mark.parametrize("degree", [0, 3])
def test_zero_point_file_is_refused(tmp_path: Path, degree: int) -> None:
    write_ply(Gaussians.empty(sh_degree=degree), tmp_path / "empty.ply")
    with pytest.raises(ValueError, match=r"empty\.ply holds 0 Gaussians"):
        read_ply(tmp_path / "empty.ply")
    assert len(read_ply(tmp_path / "empty.ply", allow_empty=True)) == 0
