"""What the preferences can say about a DepthSplat checkpoint from its file name alone.

The *Generator Weights* preference takes prosplat's ``.safetensors`` or a DepthSplat
``.pth``. Reading a 150 MB-1.4 GB pickle to learn its variant would stall the preferences
panel (and needs torch, which Blender's Python may lack), so the panel reads the released
name (``depthsplat-gs-small-re10k-256x256-view2-cfeab6b1.pth``: model size, training
resolution) and says what that implies: the licence of the monocular weights inside and an
*Input Size* to match. The worker reads the real variant from the file's keys when it loads
it, and the reconstruct report names it (:func:`describe_generator`).

No bpy and no torch here, so it is tested without Blender.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

#: Suffixes the worker sends to DepthSplat's loader (``prosplat.pipeline.model.DEPTHSPLAT_SUFFIXES``,
#: repeated so the add-on does not import prosplat, and torch, to draw its preferences).
SUFFIXES = (".pth", ".pt", ".ckpt")

#: DepthSplat's model sizes: the Depth Anything V2 ViT inside and its licence.
MODELS = {
    "small": ("ViT-S", "MIT + Apache-2.0 (Depth Anything V2 ViT-S): commercial use allowed"),
    "base": ("ViT-B", "MIT + CC-BY-NC-4.0 (Depth Anything V2 ViT-B): non-commercial use only"),
    "large": ("ViT-L", "MIT + CC-BY-NC-4.0 (Depth Anything V2 ViT-L): non-commercial use only"),
}
VIT_TO_MODEL = {"vits": "small", "vitb": "base", "vitl": "large"}

_NAME = re.compile(
    r"depthsplat-(?P<kind>gs|depth)-(?P<model>small|base|large)-.*?(?P<h>\d+)x(?P<w>\d+)"
)


@dataclass(frozen=True)
class FileHint:
    """What a DepthSplat file name says (``model`` None when the name is not a released one)."""

    model: str | None  # "small" | "base" | "large"
    depth_only: bool  # a depthsplat-depth-* file: depth, no Gaussians
    trained: tuple[int, int] | None  # (H, W) the file was trained at

    @property
    def licence(self) -> str:
        if self.model is None:
            return (
                "licence: small (ViT-S) files are MIT + Apache-2.0; base and large (ViT-B/L) "
                "are MIT + CC-BY-NC-4.0, non-commercial only"
            )
        return MODELS[self.model][1]

    def lines(self, input_size: int) -> list[str]:
        """What the preferences panel shows under the file, given the *Input Size*."""
        if self.depth_only:
            return [
                "A DepthSplat depth checkpoint: it predicts depth only, no Gaussians;",
                "use a depthsplat-gs-* file",
            ]
        out = []
        if self.model is None:
            out.append("DepthSplat checkpoint (variant read from the file when it loads)")
        else:
            out.append(f"DepthSplat {self.model} ({MODELS[self.model][0]} monocular branch)")
        out.append(self.licence)
        if self.trained is None:
            out.append(
                "Released files were trained at 256x256, 256x448 or 448x768: set Input Size "
                "to that long side"
            )
        else:
            h, w = self.trained
            long_side = max(h, w)
            out.append(
                f"Trained at {h}x{w}: Input Size {long_side} matches it"
                + (
                    f" (now {input_size}; lower is faster, coarser)"
                    if input_size != long_side
                    else ""
                )
            )
        out.append("Images are scaled to multiples of 32 px, which every DepthSplat variant takes")
        return out


def is_depthsplat_path(path: str) -> bool:
    """Whether the worker will load ``path`` as a DepthSplat checkpoint (by its suffix)."""
    return Path(path.strip()).suffix.lower() in SUFFIXES if path and path.strip() else False


def hint(path: str) -> FileHint:
    """The hint for a DepthSplat file from its name (fine-tuned files keep the released
    name's stem, so they are recognised too)."""
    m = _NAME.search(Path(path).name.lower())
    if m is None:
        return FileHint(None, False, None)
    return FileHint(m["model"], m["kind"] == "depth", (int(m["h"]), int(m["w"])))


def describe_generator(info: dict | None) -> str:
    """The reconstruct report's note on the generator: empty for prosplat's own, else the
    DepthSplat variant that the worker loaded and whether it is for non-commercial use."""
    if not info or info.get("kind") != "depthsplat":
        return ""
    model = VIT_TO_MODEL.get(str(info.get("vit")), str(info.get("vit")))
    nc = " (non-commercial licence)" if "non-commercial" in str(info.get("licence", "")) else ""
    return f" with DepthSplat {model}{nc}"
