"""A torch Dataset over many scene folders, sampling input/target subsets per item."""

from __future__ import annotations

import random
from collections import OrderedDict
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import torch
from torch import Tensor
from torch.utils.data import Dataset

from prosplat.data.scene import SceneData, load_scene

if TYPE_CHECKING:
    from prosplat.data.packed import Pack


def find_scenes(root: str | Path) -> list[Path]:
    """Scene folders under ``root`` (those holding a transforms.json), sorted by name.

    Half-rendered scenes never appear: the renderer builds each in a hidden
    ``.NAME.partial-PID`` folder (which holds a transforms.json just before it is renamed into
    place), and hidden folders are skipped.
    """
    root = Path(root)
    if (root / "transforms.json").is_file():
        return [root]
    if not root.is_dir():
        raise FileNotFoundError(f"no scene folder or dataset folder at {root}")
    found = (p.parent for p in root.glob("*/transforms.json"))
    return sorted(p for p in found if not p.name.startswith("."))


def scene_sources(roots: list[str | Path] | str | Path) -> list[Path | tuple[Pack, int]]:
    """Every scene of ``roots`` (dataset folders, scene folders and scene packs, ``.npz``), in
    order: a scene folder, or (pack, index in the pack). :func:`load_source` loads one."""
    from prosplat.data.packed import PACK_SUFFIX, Pack

    roots = [roots] if isinstance(roots, (str, Path)) else roots
    out: list[Path | tuple[Pack, int]] = []
    for r in roots:
        if Path(r).suffix == PACK_SUFFIX:
            pack = Pack(r)
            out += [(pack, i) for i in range(len(pack))]
        else:
            out += find_scenes(r)
    return out


def source_name(source: Path | tuple[Pack, int]) -> str:
    """The scene folder's name (in a pack: the name it was packed under)."""
    return source[0].index[source[1]]["name"] if isinstance(source, tuple) else source.name


def load_source(source: Path | tuple[Pack, int], load_depth: bool = True) -> SceneData:
    """Load one entry of :func:`scene_sources` (``load_depth=False``: without its depth)."""
    if isinstance(source, tuple):
        return source[0].scene(source[1], load_depth=load_depth)
    return load_scene(source, load_depth=load_depth)


class ItemKey(NamedTuple):
    """An index that also fixes the epoch and the number of input views of one item.

    A training loop passes these through a batch sampler so that every item of a step shares
    one view count and the draw does not depend on ``set_epoch`` having reached the worker
    processes of a DataLoader.
    """

    index: int
    epoch: int
    n_inputs: int


def _check_inputs(n_inputs: int) -> int:
    if not 2 <= n_inputs <= 6:
        raise ValueError(f"n_inputs must be 2-6, got {n_inputs}")
    return n_inputs


class SceneDataset(Dataset):
    """Items are dicts of tensors from one scene (default collate stacks them):

    ``input_images [N,3,H,W]``, ``input_K [N,3,3]``, ``input_w2c [N,4,4]``,
    ``target_images [M,3,H,W]``, ``target_K``, ``target_w2c``, ``target_depths [M,H,W]``,
    ``input_depths [N,H,W]``, ``near``/``far`` (scalars over the inputs), ``scene`` index.

    ``roots`` may also name scene packs (``.npz``, :mod:`prosplat.data.packed`).

    Scenes are loaded on demand and kept in a least-recently-used cache of ``cache_size``
    scenes, so memory stays bounded however many scenes the dataset holds (a 128² scene with
    12 views and depth is ~2.4 MB; the old keep-everything cache grew to GBs on real sets).

    Args:
        roots: dataset folders (or scene folders).
        n_inputs: views per item, drawn from the scene's input views (2-6); an
            :class:`ItemKey` index overrides it per item.
        n_targets: targets per item, drawn from its target views.
        seed: sampling is a pure function of (seed, epoch, index, n_inputs).
        cache_size: scenes kept in memory (0 = load every item from disk).
        any_view: draw inputs and targets from all of a scene's views, not from its
            input/target split: a 16-view trajectory then gives a new rig (baseline,
            interpolation or extrapolation targets) every time it is drawn.
    """

    def __init__(
        self,
        roots: list[str | Path] | str | Path,
        n_inputs: int = 2,
        n_targets: int = 1,
        seed: int = 0,
        cache_size: int = 32,
        any_view: bool = False,
    ):
        # each scene: a folder, or (pack, index in the pack)
        self.folders = scene_sources(roots)
        if not self.folders:
            raise FileNotFoundError(f"no scenes (folders with transforms.json) under {roots}")
        if cache_size < 0:
            raise ValueError(f"cache_size must be >= 0 scenes, got {cache_size}")
        self.n_inputs = _check_inputs(n_inputs)
        self.n_targets, self.seed, self.epoch, self.cache_size = n_targets, seed, 0, cache_size
        self.any_view = any_view
        self._cache: OrderedDict[int, SceneData] = OrderedDict()

    def set_epoch(self, epoch: int) -> None:
        """Draw different subsets each epoch (still reproducible)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.folders)

    @property
    def cached(self) -> tuple[int, ...]:
        """Indices of the scenes in memory, least recently used first."""
        return tuple(self._cache)

    def scene(self, index: int) -> SceneData:
        """Scene ``index``, from the cache or loaded now (evicting the least recently used)."""
        sc = self._cache.get(index)
        if sc is not None:
            self._cache.move_to_end(index)
            return sc
        sc = load_source(self.folders[index])
        if self.cache_size > 0:
            self._cache[index] = sc
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        return sc

    def __getitem__(self, key: int | ItemKey) -> dict[str, Tensor]:
        if isinstance(key, tuple):
            index, epoch, n_inputs = ItemKey(*key)
            _check_inputs(n_inputs)
        else:
            index, epoch, n_inputs = int(key), self.epoch, self.n_inputs
        sc = self.scene(index)
        # A string seed: the same draw on every platform and Python build (no hash()).
        rng = random.Random(f"prosplat-item/{self.seed}/{epoch}/{index}/{n_inputs}")
        ins, tgs = sc.input_indices, sc.target_indices
        if self.any_view:
            if len(sc) < n_inputs + self.n_targets:
                raise ValueError(
                    f"{sc.folder}: has {len(sc)} views, the dataset asks for {n_inputs} inputs + "
                    f"{self.n_targets} targets; render scenes with more views"
                )
            ins = sorted(rng.sample(range(len(sc)), n_inputs))
            tgs = [i for i in range(len(sc)) if i not in ins]
        if len(ins) < n_inputs or len(tgs) < self.n_targets:
            raise ValueError(
                f"{sc.folder}: has {len(ins)} inputs / {len(tgs)} targets, the dataset asks for "
                f"{n_inputs} / {self.n_targets}; render scenes with more views"
            )
        inp = sorted(rng.sample(ins, n_inputs))
        tgt = sorted(rng.sample(tgs, self.n_targets))

        def cams(idx: list[int]) -> tuple[Tensor, Tensor]:
            return (
                torch.stack([sc.cameras[i].K.float() for i in idx]),
                torch.stack([sc.cameras[i].world_to_cam.float() for i in idx]),
            )

        ik, iw = cams(inp)
        tk, tw = cams(tgt)
        item = {
            "input_images": sc.images[inp],
            "input_K": ik,
            "input_w2c": iw,
            "target_images": sc.images[tgt],
            "target_K": tk,
            "target_w2c": tw,
            "near": sc.near[inp].min(),
            "far": sc.far[inp].max(),
            "scene": torch.tensor(index),
        }
        if sc.depths is not None:
            item["input_depths"] = sc.depths[inp]
            item["target_depths"] = sc.depths[tgt]
        return item
