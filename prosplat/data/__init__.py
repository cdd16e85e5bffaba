"""Datasets of Blender-rendered scenes: loading, rigs, overlap, splits (no bpy)."""

from prosplat.data.dataset import SceneDataset, find_scenes
from prosplat.data.overlap import covisibility, overlap_matrix
from prosplat.data.rigs import Rig, choose_rig, farthest_point_sampling
from prosplat.data.scene import SceneData, load_scene
from prosplat.data.splits import SPLITS, split_of

__all__ = [
    "SPLITS",
    "Rig",
    "SceneData",
    "SceneDataset",
    "choose_rig",
    "covisibility",
    "farthest_point_sampling",
    "find_scenes",
    "load_scene",
    "overlap_matrix",
    "split_of",
]
