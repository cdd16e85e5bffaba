"""One rendered scene folder: ``transforms.json`` + PNG images + depth EXRs -> tensors.

Folder layout (written by ``prosplat scenes render``)::

    transforms.json     nerfstudio form; per frame "split": "input" | "target",
                        "target_kind" (targets), "file_path", "depth_file_path", "near", "far";
                        top level "near", "far", "seed", "family", "name", "split", ...
    images/NNN.png      8-bit sRGB (Blender, Standard view transform)
    depth/NNN.exr       float32 z along the optical axis, scene units; 0 = no surface (sky)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.convert.nerfstudio import read_transforms
from prosplat.core.camera import Camera
from prosplat.core.image_io import read_depth, read_image

REQUIRED_META = ("near", "far", "seed", "family")


@dataclass
class SceneData:
    """A scene's views. images [V,3,H,W] float32 sRGB in [0,1]; depths [V,H,W] (0 = none);
    near/far [V] per view; splits[v] in {"input","target"}; target_kinds[v] for targets."""

    images: Tensor
    depths: Tensor | None
    cameras: list[Camera]
    near: Tensor
    far: Tensor
    splits: list[str]
    target_kinds: list[str | None]
    meta: dict[str, Any] = field(default_factory=dict)
    folder: Path | None = None

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def input_indices(self) -> list[int]:
        return [i for i, s in enumerate(self.splits) if s == "input"]

    @property
    def target_indices(self) -> list[int]:
        return [i for i, s in enumerate(self.splits) if s == "target"]

    def select(self, indices: list[int]) -> SceneData:
        """The views ``indices`` (in that order)."""
        idx = torch.as_tensor(indices, dtype=torch.long)
        return SceneData(
            images=self.images[idx],
            depths=None if self.depths is None else self.depths[idx],
            cameras=[self.cameras[i] for i in indices],
            near=self.near[idx],
            far=self.far[idx],
            splits=[self.splits[i] for i in indices],
            target_kinds=[self.target_kinds[i] for i in indices],
            meta=self.meta,
            folder=self.folder,
        )


def _positive_number(value: Any, what: str) -> float:
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{what} must be a positive finite number, got {value!r}")
    return float(value)


def load_scene(folder: str | Path, load_depth: bool = True) -> SceneData:
    """Load a scene folder. Raises FileNotFoundError / ValueError naming the file and the fix."""
    folder = Path(folder)
    if not (folder / "transforms.json").is_file():
        raise FileNotFoundError(
            f"{folder} is not a scene folder (no transforms.json); render one with "
            f"`prosplat scenes render --out {folder.parent}`"
        )
    tf = read_transforms(folder)
    missing = [k for k in REQUIRED_META if k not in tf.meta]
    if missing:
        raise ValueError(f"{folder / 'transforms.json'} lacks top-level {missing}")
    images, depths, near, far, splits, kinds = [], [], [], [], [], []
    for i, frame in enumerate(tf.frames):
        where = f"{folder / 'transforms.json'} frame {i} ({frame.file_path})"
        split = frame.extra.get("split")
        if split not in ("input", "target"):
            raise ValueError(f"{where}: 'split' must be 'input' or 'target', got {split!r}")
        img = read_image(folder / frame.file_path)
        if img.shape[1:] != (frame.camera.height, frame.camera.width):
            raise ValueError(
                f"{where}: image is {img.shape[2]}x{img.shape[1]} but the camera says "
                f"{frame.camera.width}x{frame.camera.height}; re-render the scene"
            )
        images.append(img)
        if load_depth:
            if "depth_file_path" not in frame.extra:
                raise ValueError(
                    f"{where}: no depth_file_path (pass load_depth=False to skip depth)"
                )
            d = read_depth(folder / frame.extra["depth_file_path"])
            if d.shape != img.shape[1:]:
                raise ValueError(
                    f"{where}: depth map is {tuple(d.shape)}, image is {tuple(img.shape[1:])}"
                )
            depths.append(d)
        n = _positive_number(frame.extra.get("near", tf.meta["near"]), f"{where}: near")
        f = _positive_number(frame.extra.get("far", tf.meta["far"]), f"{where}: far")
        if not n < f:
            raise ValueError(f"{where}: near {n} must be below far {f}")
        near.append(n)
        far.append(f)
        splits.append(split)
        kinds.append(frame.extra.get("target_kind"))
    sizes = {tuple(im.shape) for im in images}
    if len(sizes) != 1:
        raise ValueError(
            f"{folder}: views differ in size {sorted(sizes)}; all views must share one size"
        )
    return SceneData(
        images=torch.stack(images),
        depths=torch.stack(depths) if load_depth else None,
        cameras=[fr.camera for fr in tf.frames],
        near=torch.tensor(near, dtype=torch.float32),
        far=torch.tensor(far, dtype=torch.float32),
        splits=splits,
        target_kinds=kinds,
        meta=tf.meta,
        folder=folder,
    )


def resized_width(width: int, height: int, size: int) -> int:
    """The width an image ``width`` x ``height`` gets resized to ``size`` px high: the aspect
    kept, rounded to a multiple of 32 (the generator's stride)."""
    return max(32, round(width * size / height / 32) * 32)


def resize_views(images: Tensor, cameras: list[Camera], size: int) -> tuple[Tensor, list[Camera]]:
    """images [V,3,H,W] -> [V,3,size,W'] (antialiased bilinear, as ``reference_at``) with their
    cameras resized to match; W' keeps the aspect ratio, rounded to a multiple of 32 (the
    generator's stride). Used to run models at another resolution than the data's."""
    h, w = images.shape[-2:]
    width = resized_width(w, h, size)
    if (h, w) == (size, width):
        return images, cameras
    out = F.interpolate(
        images, size=(size, width), mode="bilinear", antialias=True, align_corners=False
    )
    return out.clamp(0, 1), [c.resized(width, size) for c in cameras]
