"""ProSplat: a few posed images -> 3D Gaussians in one forward pass -> enhanced novel views.

The library never imports ``bpy``; the Blender add-on (``addon/``) is a thin layer on top.
"""

from prosplat.core.camera import Camera, CameraBatch, stack_cameras
from prosplat.core.gaussians import Gaussians
from prosplat.core.ply import read_ply, write_ply
from prosplat.improve.epipolar import fundamental_matrix
from prosplat.improve.mori import mori_scores, overlap_scores, select_reference
from prosplat.pipeline.enhance import EnhancedView
from prosplat.pipeline.model import ProSplat
from prosplat.pipeline.reconstruction import Reconstruction
from prosplat.pipeline.trust import TrustEstimate, leave_one_out
from prosplat.render import RenderOutput, render

__all__ = [
    "Camera",
    "CameraBatch",
    "EnhancedView",
    "Gaussians",
    "ProSplat",
    "Reconstruction",
    "RenderOutput",
    "TrustEstimate",
    "fundamental_matrix",
    "leave_one_out",
    "mori_scores",
    "overlap_scores",
    "read_ply",
    "render",
    "select_reference",
    "stack_cameras",
    "write_ply",
]
__version__ = "0.1.0"
