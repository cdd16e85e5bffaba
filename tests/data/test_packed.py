"""Scene packs (prosplat.data.packed) and the v2 training data path: packs read like folders,
any-view draws, and the per-step downsampling of a batch."""

from __future__ import annotations

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

from prosplat.cli import main
from prosplat.data import SceneDataset
from prosplat.data.dataset import ItemKey
from prosplat.data.packed import Pack, pack_scenes
from prosplat.data.scene import load_scene
from prosplat.metrics import psnr
from prosplat.train.batches import crop_batch, resize_batch, step_view
from prosplat.train.generator_config import TrainConfig, train_sizes


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes")
    for k in range(3):
        write_synthetic_scene(root / f"scene_{k}", size=32, n_views=8)
    return root


@pytest.fixture(scope="module")
def pack(scenes, tmp_path_factory):
    folders = sorted(scenes.iterdir())
    return pack_scenes(folders, tmp_path_factory.mktemp("packs") / "train_000.npz")


def test_a_pack_holds_the_scenes_it_was_made_from(scenes, pack):
    p = Pack(pack)
    assert p.names() == ["scene_0", "scene_1", "scene_2"]
    for i, folder in enumerate(sorted(scenes.iterdir())):
        a, b = load_scene(folder), p.scene(i)
        assert b.splits == a.splits and b.target_kinds == a.target_kinds
        assert float(psnr(b.images, a.images).min()) > 35  # JPEG q95
        rel = (b.depths - a.depths).abs() / a.depths.clamp_min(1e-6)
        assert float(rel[a.depths > 0].max()) < 1e-3  # float16
        for ca, cb in zip(a.cameras, b.cameras):
            assert torch.allclose(ca.K.double(), cb.K.double())
            assert torch.allclose(ca.world_to_cam.double(), cb.world_to_cam.double())
        assert torch.equal(a.near, b.near) and torch.equal(a.far, b.far)


def test_a_pack_without_depth_is_smaller_and_reads_the_same_images(scenes, pack, tmp_path):
    folders = sorted(scenes.iterdir())
    bare = Pack(pack_scenes(folders, tmp_path / "bare.npz", depth=False))
    full = Pack(pack)
    # the depth maps are a large share of a pack
    assert bare.path.stat().st_size < 0.8 * full.path.stat().st_size
    assert full.has_depth and not bare.has_depth
    for i in range(len(full)):
        a, b = full.scene(i), bare.scene(i)
        assert b.depths is None and a.depths is not None
        assert torch.equal(a.images, b.images)  # the same JPEG bytes
        assert b.splits == a.splits and torch.equal(a.near, b.near)
    item = SceneDataset(bare.path, n_inputs=2, n_targets=2, seed=3)[ItemKey(1, 0, 2)]
    assert "input_depths" not in item and "target_depths" not in item


def test_a_lower_jpeg_quality_packs_smaller_and_less_exact_images(scenes, pack, tmp_path):
    folders = sorted(scenes.iterdir())
    low = Pack(pack_scenes(folders, tmp_path / "q60.npz", depth=False, jpeg_quality=60))
    bare = Pack(pack_scenes(folders, tmp_path / "q95.npz", depth=False))
    assert low.path.stat().st_size < 0.8 * bare.path.stat().st_size
    for i, folder in enumerate(folders):
        png = load_scene(folder).images
        fine = float(psnr(bare.scene(i).images, png).mean())
        coarse = float(psnr(low.scene(i).images, png).mean())
        assert 25 < coarse < fine - 2
    for bad in (0, 96):
        with pytest.raises(ValueError, match="jpeg_quality"):
            pack_scenes(folders, tmp_path / f"q{bad}.npz", jpeg_quality=bad)


def test_rounded_depth_packs_smaller_within_its_stated_error(scenes, pack, tmp_path):
    folders = sorted(scenes.iterdir())
    coarse = Pack(pack_scenes(folders, tmp_path / "d6.npz", depth_bits=6))
    assert coarse.path.stat().st_size < Pack(pack).path.stat().st_size
    for i, folder in enumerate(folders):
        exact = load_scene(folder).depths
        rel = (coarse.scene(i).depths - exact).abs() / exact.clamp_min(1e-6)
        assert 2**-10 < float(rel[exact > 0].max()) <= 2**-7 + 2**-11  # 2^-(bits+1) + float16
        assert torch.equal(coarse.scene(i).depths == 0, exact == 0)
        assert torch.equal(coarse.scene(i).images, Pack(pack).scene(i).images)
    with pytest.raises(ValueError, match="depth_bits"):
        pack_scenes(folders, tmp_path / "d11.npz", depth_bits=11)


def test_training_with_depth_terms_refuses_a_pack_without_depth(scenes, tmp_path):
    from prosplat.train.generator import train

    bare = pack_scenes(sorted(scenes.iterdir()), tmp_path / "bare.npz", depth=False)
    cfg = TrainConfig(data=str(bare), out=str(tmp_path / "run"), steps=1, inputs=2,
                      input_depth_weight=1.0, lpips_weight=0.0)  # fmt: skip
    with pytest.raises(ValueError, match="--input-depth-weight need it"):
        train(cfg, progress=False)


def test_a_pack_is_never_replaced_and_must_be_npz(scenes, pack):
    with pytest.raises(FileExistsError, match="exists"):
        pack_scenes([scenes / "scene_0"], pack)
    with pytest.raises(ValueError, match=".npz"):
        pack_scenes([scenes / "scene_0"], pack.with_suffix(".zip"))
    with pytest.raises(FileNotFoundError, match="no pack"):
        Pack(pack.with_name("missing.npz"))


def test_the_dataset_reads_packs_and_folders_alike(scenes, pack):
    folders = SceneDataset(scenes, n_inputs=2, n_targets=2, seed=3)
    packed = SceneDataset(pack, n_inputs=2, n_targets=2, seed=3)
    assert len(folders) == len(packed) == 3
    a, b = folders[ItemKey(1, 0, 3)], packed[ItemKey(1, 0, 3)]
    assert torch.equal(a["input_w2c"], b["input_w2c"])  # the same draw of views
    assert float(psnr(b["target_images"], a["target_images"]).min()) > 35


def test_any_view_draws_inputs_from_every_view(pack):
    ds = SceneDataset(pack, n_inputs=3, n_targets=2, seed=0, any_view=True)
    split = SceneDataset(pack, n_inputs=3, n_targets=2, seed=0)
    sc = ds.scene(0)
    target_poses = {
        tuple(sc.cameras[i].world_to_cam.float().double().flatten().tolist())
        for i in sc.target_indices
    }
    drawn_from_targets = 0
    for epoch in range(20):
        item = ds[ItemKey(0, epoch, 3)]
        ins = {tuple(m.double().flatten().tolist()) for m in item["input_w2c"]}
        tgs = {tuple(m.double().flatten().tolist()) for m in item["target_w2c"]}
        assert not ins & tgs  # a view is never both
        drawn_from_targets += bool(ins & target_poses)
        # without any_view inputs only ever come from the input split
        fixed = {
            tuple(m.double().flatten().tolist()) for m in split[ItemKey(0, epoch, 3)]["input_w2c"]
        }
        assert not fixed & target_poses
    assert drawn_from_targets > 0


def test_resize_batch_keeps_geometry_and_drops_depth_edges():
    b, v, h = 1, 2, 64
    images = torch.rand(b, v, 3, h, h)
    depth = torch.full((b, v, h, h), 2.0)
    depth[..., :, 33:] = 4.0  # an edge inside the 2x2 block of columns 32-33
    depth[..., :8, :] = 0.0  # sky: rows 0-7 hit nothing
    depth[..., 8, :] = 0.0  # row 8 is half sky, half surface after resizing (rows 8-9)
    K = torch.tensor([[50.0, 0, 32], [0, 50, 32], [0, 0, 1]]).expand(b, v, 3, 3)
    batch = {
        "input_images": images,
        "target_images": images,
        "input_depths": depth,
        "target_depths": depth,
        "input_K": K,
        "target_K": K,
    }
    out = resize_batch(batch, 32)
    assert out["input_images"].shape == (b, v, 3, 32, 32)
    assert torch.allclose(out["input_K"][0, 0, 0], torch.tensor([25.0, 0, 16]))
    d = out["input_depths"][0, 0]
    assert torch.allclose(d[5:, :16], torch.full_like(d[5:, :16], 2.0))
    assert (d[:, 16] == 0).all()  # the block that straddles the edge is not supervised
    assert torch.allclose(d[5:, 17:], torch.full_like(d[5:, 17:], 4.0))
    # a footprint half on the sky (row 4: rows 8-9) is no surface either: not a blend with 0
    assert (d[:5] == 0).all()
    # a constant image stays constant (antialiasing does not darken borders)
    flat = resize_batch({**batch, "input_images": torch.full_like(images, 0.25)}, 32)
    assert torch.allclose(flat["input_images"], torch.tensor(0.25), atol=1e-6)
    with pytest.raises(ValueError, match="render larger"):
        resize_batch(batch, 128)


def _square_batch(h: int, v: int = 2) -> dict[str, torch.Tensor]:
    images = torch.rand(1, v, 3, h, h)
    K = torch.tensor([[50.0, 0, h / 2], [0, 50, h / 2], [0, 0, 1]]).expand(1, v, 3, 3)
    depth = torch.full((1, v, h, h), 3.0)
    return {
        "input_images": images,
        "target_images": images.flip(-1),
        "input_depths": depth,
        "target_depths": depth,
        "input_K": K,
        "target_K": K.clone(),
    }


def test_targets_at_a_multiple_of_the_input_size():
    """target_scale: inputs at the step's size, targets at k x it (at most the data's), each
    group's intrinsics and depth following its own size; a crop takes the targets' window."""
    batch = _square_batch(128)
    out = resize_batch(batch, 32, 64)
    assert out["input_images"].shape[-2:] == (32, 32) and out["input_depths"].shape[-2:] == (32, 32)
    assert out["target_images"].shape[-2:] == (64, 64) and out["target_depths"].shape[-2:] == (
        64,
        64,
    )
    assert torch.allclose(out["input_K"][0, 0, 0], torch.tensor([12.5, 0, 16]))
    assert torch.allclose(out["target_K"][0, 0, 0], torch.tensor([25.0, 0, 32]))
    # the targets are the same pixels as a plain downsample to 64
    assert torch.equal(out["target_images"], resize_batch(batch, 64)["target_images"])
    with pytest.raises(ValueError, match="render larger"):
        resize_batch(batch, 64, 256)

    cfg = TrainConfig(data="", out="", sizes="32", target_scale=2)
    view = step_view(batch, cfg, step=0)
    assert view["input_images"].shape[-1] == 32 and view["target_images"].shape[-1] == 64
    # a scale beyond the data stops at the data's size
    view = step_view(batch, TrainConfig(data="", out="", sizes="64", target_scale=4), step=0)
    assert view["input_images"].shape[-1] == 64 and view["target_images"].shape[-1] == 128
    assert torch.equal(view["target_K"], batch["target_K"])
    # crops: a 64-px window at the data's scale for the targets, its 32-px downsample for inputs
    cropped = step_view(
        batch, TrainConfig(data="", out="", sizes="32", target_scale=2, crop_prob=1.0), 0
    )
    assert cropped["target_images"].shape[-1] == 64 and cropped["input_images"].shape[-1] == 32
    K_t, K_i = cropped["target_K"][0, 0], cropped["input_K"][0, 0]
    assert K_t[0, 0] == 50.0 and torch.allclose(K_i[:2, :3], K_t[:2, :3] / 2)
    with pytest.raises(ValueError, match="target_scale"):
        TrainConfig(data="", out="", target_scale=0)


def test_train_sizes_parse_and_refuse_bad_values():
    assert train_sizes("128,64") == (64, 128)
    assert train_sizes("") == ()
    for bad in ("48", "64,abc", "0"):
        with pytest.raises(ValueError):
            train_sizes(bad)


def test_the_pack_command_splits_and_never_overwrites(scenes, tmp_path, capsys):
    out = tmp_path / "p" / "train"
    args = ["scenes", "pack", "--data", str(scenes), "--out", str(out), "--max-mb", "0.02"]
    with pytest.raises(SystemExit) as done:
        main(args)
    assert done.value.code == 0
    packs = sorted(out.parent.glob("train_*.npz"))
    assert len(packs) >= 2  # a tiny bound forces several packs
    assert sum(len(Pack(p)) for p in packs) == 3
    with pytest.raises(FileExistsError):
        main(args)
    with pytest.raises(SystemExit) as done:
        main([*args[:-2], "--max-mb", "1", "--no-depth", "--out", str(tmp_path / "bare"),
              "--jpeg-quality", "80", "--depth-bits", "7"])  # fmt: skip
    assert done.value.code == 0
    (bare,) = tmp_path.glob("bare_*.npz")
    for bad in (["--jpeg-quality", "0"], ["--depth-bits", "11"], ["--depth-bits", "x"]):
        with pytest.raises(SystemExit) as done:  # a usage error, before anything is written
            main([*args[:-2], "--out", str(tmp_path / "bad"), *bad])
        assert done.value.code == 2
    assert not list(tmp_path.glob("bad*"))
    assert not Pack(bare).has_depth and len(Pack(bare)) == 3


def test_a_crop_keeps_every_pixel_on_its_ray():
    """crop_batch: the cropped camera sees the same pixels (same rays), depth untouched."""
    from prosplat.core.camera import Camera

    h = 64
    img = torch.rand(1, 1, 3, h, h)
    depth = torch.rand(1, 1, h, h) + 1
    K = torch.tensor([[50.0, 0, 30], [0, 55, 33], [0, 0, 1]])[None, None]
    w2c = torch.eye(4)[None, None]
    batch = {"input_images": img, "input_depths": depth, "input_K": K, "input_w2c": w2c}
    out = crop_batch(batch, 32, top=5, left=20)
    assert torch.equal(out["input_images"][0, 0], img[0, 0, :, 5:37, 20:52])
    assert torch.equal(out["input_depths"][0, 0], depth[0, 0, 5:37, 20:52])
    full = Camera(K[0, 0], w2c[0, 0], h, h)
    crop = Camera(out["input_K"][0, 0], w2c[0, 0], 32, 32)
    p = torch.tensor([[0.3, -0.2, 2.0]], dtype=full.K.dtype)
    uv_full, uv_crop = full.project(p)[0], crop.project(p)[0]
    assert torch.allclose(uv_full[0] - torch.tensor([20.0, 5.0], dtype=uv_full.dtype), uv_crop[0])
    assert torch.equal(batch["input_K"], K)  # the input batch is not modified
    with pytest.raises(ValueError, match="does not fit"):
        crop_batch(batch, 32, top=40, left=0)
