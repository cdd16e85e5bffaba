"""SceneDataset: the bounded scene cache, per-item view counts, and items independent of both."""

from __future__ import annotations

import pytest
import torch
from synthetic_scenes import write_synthetic_scene

import prosplat.data.dataset as dataset_module
from prosplat.data import SceneDataset
from prosplat.data.dataset import ItemKey


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Four small scenes with 5 input and 4 target views each."""
    root = tmp_path_factory.mktemp("scenes")
    for k in range(4):
        write_synthetic_scene(root / f"scene_{k}", size=16, n_views=9)
    return root


@pytest.fixture
def loads(monkeypatch):
    """Scene indices in the order they are read from disk."""
    seen: list[str] = []
    real = dataset_module.load_scene

    def counting(folder, **kwargs):
        seen.append(folder.name)
        return real(folder, **kwargs)

    monkeypatch.setattr(dataset_module, "load_scene", counting)
    return seen


def test_the_cache_keeps_the_most_recently_used_scenes(scenes, loads):
    ds = SceneDataset(scenes, n_inputs=2, cache_size=2)
    assert ds.cached == ()  # nothing read up front
    ds[0], ds[1], ds[0]
    assert loads == ["scene_0", "scene_1"] and ds.cached == (1, 0)
    ds[2]  # evicts scene 1, the least recently used
    assert ds.cached == (0, 2)
    ds[0]
    assert loads == ["scene_0", "scene_1", "scene_2"]  # still cached: not read again
    ds[1]  # was evicted: read again
    assert loads[-1] == "scene_1" and ds.cached == (0, 1)
    for i in range(len(ds)):
        ds[i]
    assert len(ds.cached) == 2  # bounded however many scenes are visited


def test_cache_size_zero_reads_every_item_from_disk(scenes, loads):
    ds = SceneDataset(scenes, n_inputs=2, cache_size=0)
    ds[3], ds[3]
    assert loads == ["scene_3", "scene_3"] and ds.cached == ()
    with pytest.raises(ValueError, match="cache_size"):
        SceneDataset(scenes, cache_size=-1)


def test_items_are_identical_with_and_without_the_cache(scenes):
    cached = SceneDataset(scenes, n_inputs=3, n_targets=2, seed=7, cache_size=1)
    uncached = SceneDataset(scenes, n_inputs=3, n_targets=2, seed=7, cache_size=0)
    keys = [0, 1, 0, 3, ItemKey(2, 5, 4), ItemKey(0, 1, 2), 1]
    for key in keys:
        a, b = cached[key], uncached[key]
        assert a.keys() == b.keys()
        for name in a:
            assert torch.equal(a[name], b[name]), (key, name)


def test_an_item_key_sets_the_epoch_and_view_count(scenes):
    ds = SceneDataset(scenes, n_inputs=2, n_targets=1, seed=0)
    item = ds[ItemKey(1, 0, 5)]
    assert item["input_images"].shape == (5, 3, 16, 16) and item["input_K"].shape == (5, 3, 3)
    assert ds[ItemKey(1, 0, 2)]["input_images"].shape[0] == 2
    # An int index uses the dataset's own count and set_epoch: the same draw as its key.
    ds.set_epoch(3)
    assert torch.equal(ds[1]["input_w2c"], ds[ItemKey(1, 3, 2)]["input_w2c"])
    # Epochs draw different subsets, reproducibly.
    per_epoch = [ds[ItemKey(1, e, 3)]["input_w2c"] for e in range(6)]
    assert any(not torch.equal(per_epoch[0], w) for w in per_epoch[1:])
    assert torch.equal(per_epoch[2], ds[ItemKey(1, 2, 3)]["input_w2c"])
    with pytest.raises(ValueError, match="2-6"):
        ds[ItemKey(1, 0, 7)]
    with pytest.raises(ValueError, match="has 5 inputs"):
        SceneDataset(scenes, n_inputs=6)[0]


def test_a_batch_sampler_of_item_keys_collates_one_view_count(scenes):
    ds = SceneDataset(scenes, n_inputs=2, n_targets=1)
    batches = [[ItemKey(0, 0, 4), ItemKey(2, 0, 4)], [ItemKey(1, 0, 2), ItemKey(3, 0, 2)]]
    loader = torch.utils.data.DataLoader(ds, batch_sampler=batches)
    shapes = [tuple(b["input_images"].shape) for b in loader]
    assert shapes == [(2, 4, 3, 16, 16), (2, 2, 3, 16, 16)]
