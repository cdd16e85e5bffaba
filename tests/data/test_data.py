"""prosplat.data without Blender: rigs, overlap, splits, scene folders and the Dataset."""

from __future__ import annotations

import json

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat import Camera
from prosplat.core.image_io import write_depth, write_image  # noqa: F401
from prosplat.data import (
    SceneDataset,
    choose_rig,
    covisibility,
    farthest_point_sampling,
    load_scene,
    overlap_matrix,
    split_of,
)
from prosplat.data.splits import family_for_seed
from prosplat.eval.demo_scene import raycast


def line_trajectory(n: int = 60):
    return [((float(i), 0.0, 1.0), (float(i), 5.0, 1.0)) for i in range(n)]


def test_fps_on_a_line_picks_the_ends_then_the_middle():
    pts = torch.tensor([[float(i), 0.0, 0.0] for i in range(11)])
    assert farthest_point_sampling(pts, 3) == [0, 10, 5]


def test_rig_inputs_span_window_and_targets_are_labelled():
    traj = line_trajectory(60)
    rig = choose_rig(traj, 4, 8, seed=7)
    assert len(rig.inputs) == 4 and list(rig.inputs) == sorted(rig.inputs)
    assert len(rig.targets) == 8 and not set(rig.targets) & set(rig.inputs)
    lo, hi = rig.inputs[0], rig.inputs[-1]
    assert hi - lo == round(0.7 * 60) - 1  # FPS on a line spans the whole window
    for t, kind in zip(rig.targets, rig.target_kinds):
        assert kind == ("interpolation" if lo < t < hi else "extrapolation")
    assert rig.target_kinds.count("interpolation") == 4
    assert choose_rig(traj, 4, 8, seed=7) == rig
    assert choose_rig(traj, 4, 8, seed=8) != rig


def test_rig_rejects_bad_counts():
    with pytest.raises(ValueError, match="2-6"):
        choose_rig(line_trajectory(), 1, 2, 0)
    with pytest.raises(ValueError, match="poses"):
        choose_rig(line_trajectory(10), 6, 8, 0)


def test_splits_are_disjoint_seed_ranges():
    assert split_of(0) == "train" and split_of(899_999) == "train"
    assert split_of(900_000) == "val" and split_of(950_000) == "test"
    with pytest.raises(ValueError, match="outside"):
        split_of(1_000_000)
    assert [family_for_seed(s) for s in range(4)] == ["room", "tabletop", "open", "room"]


def plane_view(shift_x: float) -> tuple[Camera, torch.Tensor]:
    """A camera looking down +z at the plane z = 4, shifted sideways; analytic depth 4."""
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[0, 3] = -shift_x
    cam = Camera.from_intrinsics(20.0, 20.0, 16.0, 16.0, 32, 32, w2c)
    return cam, torch.full((32, 32), 4.0)


def test_covisibility_of_shifted_views_of_a_plane():
    a, da = plane_view(0.0)
    b, db = plane_view(0.0)
    assert covisibility(a, da, b, db) == 1.0
    # The image is 32 px = 32/20*4 = 6.4 scene units wide at depth 4: a shift of 3.2 is half.
    c, dc = plane_view(3.2)
    assert covisibility(a, da, c, dc) == pytest.approx(0.5, abs=1 / 32)
    occluded = torch.full((32, 32), 2.0)  # something nearer hides the plane from c
    assert covisibility(a, da, c, occluded) == 0.0
    sky = torch.zeros(32, 32)
    assert covisibility(a, sky, c, dc) == 0.0
    m = overlap_matrix([a, b, c], [da, db, dc])
    assert torch.equal(m, m.T) and m[0, 1] == 1 and m[0, 2] == pytest.approx(0.5, abs=1 / 32)


def test_load_scene_round_trip(tmp_path):
    cams = write_synthetic_scene(tmp_path / "s")
    sc = load_scene(tmp_path / "s")
    assert sc.images.shape == (5, 3, 32, 32) and sc.depths.shape == (5, 32, 32)
    assert sc.input_indices == [0, 2, 4] and sc.target_indices == [1, 3]
    assert sc.target_kinds[1] == "interpolation" and sc.target_kinds[0] is None
    for a, b in zip(sc.cameras, cams):
        torch.testing.assert_close(a.world_to_cam, b.world_to_cam, atol=1e-9, rtol=0)
    torch.testing.assert_close(sc.depths[0], raycast(cams[0])[0].float())
    assert (sc.near < sc.far).all()
    sub = sc.select([4, 1])
    assert sub.splits == ["input", "target"] and sub.images.shape[0] == 2


def test_load_scene_errors_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="transforms.json"):
        load_scene(tmp_path)
    write_synthetic_scene(tmp_path / "s")
    (tmp_path / "s" / "images" / "001.png").unlink()
    with pytest.raises(FileNotFoundError, match="001.png"):
        load_scene(tmp_path / "s")
    write_synthetic_scene(tmp_path / "t")
    tf = json.loads((tmp_path / "t" / "transforms.json").read_text())
    tf["frames"][2]["split"] = "train"
    (tmp_path / "t" / "transforms.json").write_text(json.dumps(tf))
    with pytest.raises(ValueError, match="split"):
        load_scene(tmp_path / "t")
    tf["frames"][2]["split"] = "input"
    tf["frames"][2]["near"] = -1.0
    (tmp_path / "t" / "transforms.json").write_text(json.dumps(tf))
    with pytest.raises(ValueError, match="near"):
        load_scene(tmp_path / "t")


def test_dataset_samples_reproducible_subsets(tmp_path):
    for k in range(2):
        write_synthetic_scene(tmp_path / f"scene_{k}")
    (tmp_path / ".scene_9.partial-1").mkdir()  # an unfinished render is never listed
    ds = SceneDataset(tmp_path, n_inputs=2, n_targets=1, seed=3)
    assert len(ds) == 2
    item = ds[0]
    assert item["input_images"].shape == (2, 3, 32, 32)
    assert item["target_images"].shape == (1, 3, 32, 32)
    assert item["input_K"].shape == (2, 3, 3) and item["target_w2c"].shape == (1, 4, 4)
    assert item["near"] < item["far"]
    again = SceneDataset(tmp_path, n_inputs=2, n_targets=1, seed=3)[0]
    assert torch.equal(item["input_images"], again["input_images"])
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=2)))
    assert batch["input_images"].shape == (2, 2, 3, 32, 32)
    with pytest.raises(ValueError, match="inputs"):
        SceneDataset(tmp_path, n_inputs=4)[0]
