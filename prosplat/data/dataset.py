"""A torch Dataset over many scene folders, sampling input/target subsets per item."""

from __future__ import annotations

import random
from pathlib import Path

import torch
from torch import Tensor
from torch.utils.data import Dataset

from prosplat.data.scene import SceneData, load_scene


def find_scenes(root: str | Path) -> list[Path]:
    """Scene folders under ``root`` (those holding a transforms.json), sorted by name.

    Half-rendered scenes never appear: the renderer moves a folder into place only when done.
    """
    root = Path(root)
    if (root / "transforms.json").is_file():
        return [root]
    if not root.is_dir():
        raise FileNotFoundError(f"no scene folder or dataset folder at {root}")
    return sorted(p.parent for p in root.glob("*/transforms.json"))


class SceneDataset(Dataset):
    """Items are dicts of tensors from one scene (default collate stacks them):

    ``input_images [N,3,H,W]``, ``input_K [N,3,3]``, ``input_w2c [N,4,4]``,
    ``target_images [M,3,H,W]``, ``target_K``, ``target_w2c``, ``target_depths [M,H,W]``,
    ``input_depths [N,H,W]``, ``near``/``far`` (scalars over the inputs), ``scene`` index.

    Args:
        roots: dataset folders (or scene folders).
        n_inputs: views per item, drawn from the scene's input views (2-6).
        n_targets: targets per item, drawn from its target views.
        seed: sampling is a pure function of (seed, epoch, index).
    """

    def __init__(
        self,
        roots: list[str | Path] | str | Path,
        n_inputs: int = 2,
        n_targets: int = 1,
        seed: int = 0,
    ):
        roots = [roots] if isinstance(roots, (str, Path)) else roots
        self.folders = [f for r in roots for f in find_scenes(r)]
        if not self.folders:
            raise FileNotFoundError(f"no scenes (folders with transforms.json) under {roots}")
        if not 2 <= n_inputs <= 6:
            raise ValueError(f"n_inputs must be 2-6, got {n_inputs}")
        self.n_inputs, self.n_targets, self.seed, self.epoch = n_inputs, n_targets, seed, 0
        self._cache: dict[int, SceneData] = {}

    def set_epoch(self, epoch: int) -> None:
        """Draw different subsets each epoch (still reproducible)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.folders)

    def scene(self, index: int) -> SceneData:
        if index not in self._cache:
            self._cache[index] = load_scene(self.folders[index])
        return self._cache[index]

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        sc = self.scene(index)
        rng = random.Random(hash((self.seed, self.epoch, index)))
        ins, tgs = sc.input_indices, sc.target_indices
        if len(ins) < self.n_inputs or len(tgs) < self.n_targets:
            raise ValueError(
                f"{sc.folder}: has {len(ins)} inputs / {len(tgs)} targets, the dataset asks for "
                f"{self.n_inputs} / {self.n_targets}; render scenes with more views"
            )
        inp = sorted(rng.sample(ins, self.n_inputs))
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
