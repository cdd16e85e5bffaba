"""The hard cases of ``prosplat bench hard``: what each one feeds the pipeline and expects.

See :mod:`prosplat.eval.bench.hard` for the table of cases and how a result is judged. Each case
maps a prepared scene to a :class:`Run` (inputs, depth range and targets that must come out
finite) or a :class:`Raises` (reconstructions that must fail with a clear error), or to a
string saying why the case does not apply to that scene.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from prosplat.core.camera import Camera
from prosplat.data.scene import SceneData

CASES: tuple[str, ...] = (
    "baseline",
    "duplicated_inputs",
    "single_view",
    "single_view_no_depth_range",
    "near_equals_far",
    "near_nonpositive",
    "depth_range_nonfinite",
    "depth_range_1e4_near",
    "depth_range_1e4_far",
    "textureless_inputs",
    "textureless",
    "specular",
    "focal_x0.1",
    "focal_x10",
    "target_focal_x0.1",
    "target_focal_x10",
    "target_is_input",
    "target_behind_inputs",
)

#: words a clear error message must contain one of (it names the offending argument)
ARGUMENT_WORDS = ("near", "far", "camera", "image", "depth", "focal", "baseline")
#: the alpha a target with nothing in front of it may reach
EMPTY_ALPHA = 1e-3


# ---- what a case runs ---------------------------------------------------------------------
@dataclass
class Target:
    camera: Camera
    gt: Tensor | None  # [3,H,W] ground truth, None where PSNR is not meaningful
    reference: int | None = None  # the input MORI must pick, if any
    empty: bool = False  # nothing may be visible (alpha < EMPTY_ALPHA)


@dataclass
class Run:
    """Run the pipeline on these inputs and targets; everything must be finite."""

    images: Tensor
    cameras: list[Camera]
    near: float | None
    far: float | None
    targets: list[Target]
    note: str = ""


@dataclass
class Raises:
    """Each (label, near, far) reconstruction must raise a clear error naming one of ``words``."""

    images: Tensor
    cameras: list[Camera]
    attempts: list[tuple[str, float | None, float | None]]
    words: tuple[str, ...]
    note: str = ""


@dataclass
class CaseScene:
    """What every case derives its inputs from."""

    data: SceneData
    name: str
    tags: set[str]
    a: int  # the two farthest-apart input views (scene indices)
    b: int
    near: float
    far: float
    targets: list[int]  # scene indices of the target views used


def _scene_name(scene: SceneData) -> str:
    if scene.folder is not None:
        return Path(scene.folder).name
    return str(scene.meta.get("name", "scene"))


def prepare(scene: SceneData, n_targets: int) -> CaseScene:
    from prosplat.data.rigs import pick_inputs

    a, b = pick_inputs(scene, 2)
    near, far = float(scene.near[[a, b]].min()), float(scene.far[[a, b]].max())
    tags = {str(t) for t in scene.meta.get("tags", [])} | {str(scene.meta.get("name", ""))}
    targets = scene.target_indices[:n_targets]
    if not targets:
        raise ValueError(f"{_scene_name(scene)}: has no target views; hard cases need at least one")
    return CaseScene(scene, _scene_name(scene), tags, a, b, near, far, targets)


def _scaled_focal(camera: Camera, factor: float) -> Camera:
    """``camera`` with fx, fy (and skew) times ``factor``: the same pose and image size."""
    K = camera.K.clone()
    K[0, :2] *= factor
    K[1, 1] *= factor
    return Camera(K, camera.world_to_cam, camera.width, camera.height)


def _scene_targets(s: CaseScene, camera_map: Callable[[Camera], Camera] | None = None) -> list:
    """The scene's targets; ground truth only when the cameras are the scene's own."""
    out = []
    for t in s.targets:
        cam = s.data.cameras[t]
        if camera_map is None:
            out.append(Target(cam, s.data.images[t]))
        else:
            out.append(Target(camera_map(cam), None))
    return out


def _behind_target(s: CaseScene, cameras: list[Camera]) -> Camera:
    """A camera behind every input, looking away from the scene.

    It sits at the inputs' centroid moved back along their mean viewing direction f by the
    rig's radius plus the scene's far depth, and looks along -f: every point in front of an
    input within ``far`` of it (so every Gaussian the generator can place) is behind it.
    """
    centers = torch.stack([c.center.double() for c in cameras])
    forward = torch.stack([c.forward.double() for c in cameras]).mean(0)
    if forward.norm() < 1e-6:  # inputs facing each other: any direction is as good
        forward = cameras[0].forward.double()
    forward = forward / forward.norm()
    centroid = centers.mean(0)
    radius = float((centers - centroid).norm(dim=-1).max())
    eye = centroid - forward * (radius + 2.0 * s.far)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    if torch.linalg.cross(up, forward).norm() < 1e-3:
        up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    ref = cameras[0]
    return Camera.look_at(eye, eye - forward, up, ref.fx, ref.width, ref.height, fy=ref.fy)


def case_plan(case: str, s: CaseScene) -> Run | Raises | str:
    """What ``case`` runs on scene ``s``; a string means not applicable (the reason)."""
    d, a, b = s.data, s.a, s.b
    images, cams = d.images[[a, b]], [d.cameras[a], d.cameras[b]]
    pair = f"inputs {a},{b}"
    if case == "baseline":
        return Run(images, cams, s.near, s.far, _scene_targets(s), pair)
    if case == "duplicated_inputs":
        return Run(
            d.images[[a, a, b, b]],
            [cams[0], cams[0], cams[1], cams[1]],
            s.near,
            s.far,
            _scene_targets(s),
            f"inputs {a},{a},{b},{b}",
        )
    if case == "single_view":
        return Run(
            d.images[[a, a]],
            [cams[0], cams[0]],
            s.near,
            s.far,
            _scene_targets(s),
            f"inputs {a},{a}",
        )
    if case == "single_view_no_depth_range":
        return Raises(
            d.images[[a, a]],
            [cams[0], cams[0]],
            [("near/far default", None, None)],
            ("camera", "near", "far"),
            f"inputs {a},{a}, no near/far",
        )
    if case == "near_equals_far":
        valid = d.depths[[a, b]] if d.depths is not None else None
        mid = (
            float(valid[valid > 0].median())
            if valid is not None and (valid > 0).any()
            else math.sqrt(s.near * s.far)
        )
        return Raises(images, cams, [(f"near=far={mid:.3g}", mid, mid)], ("near", "far"))
    if case == "near_nonpositive":
        return Raises(
            images, cams, [("near=0", 0.0, s.far), ("near=-far", -s.far, s.far)], ("near",)
        )
    if case == "depth_range_nonfinite":
        attempts = [("near=NaN", math.nan, s.far), ("far=NaN", s.near, math.nan)]
        attempts.append(("far=Inf", s.near, math.inf))
        return Raises(images, cams, attempts, ("near", "far"))
    if case == "depth_range_1e4_near":
        near = s.far / 1e4
        return Run(images, cams, near, s.far, _scene_targets(s), f"near/far {near:.3g}/{s.far:.3g}")
    if case == "depth_range_1e4_far":
        far = s.near * 1e4
        return Run(images, cams, s.near, far, _scene_targets(s), f"near/far {s.near:.3g}/{far:.3g}")
    if case == "textureless_inputs":
        colour = images.mean(dim=(0, 2, 3))  # [3]
        flat = colour[None, :, None, None].expand_as(images).contiguous()
        rgb = ",".join(f"{float(c):.2f}" for c in colour)
        # the targets' ground truth shows the real scene, not the flat one: no PSNR
        return Run(flat, cams, s.near, s.far, _scene_targets(s, lambda c: c), f"flat ({rgb})")
    if case in ("textureless", "specular"):
        if case not in s.tags:
            return f"n/a (no {case} scene)"
        return Run(images, cams, s.near, s.far, _scene_targets(s), f"Blender {case} scene; {pair}")
    if case.startswith(("focal_x", "target_focal_x")):
        factor = float(case.rsplit("_x", 1)[1])
        scale = lambda c: _scaled_focal(c, factor)  # noqa: E731
        if case.startswith("target_"):
            return Run(
                images, cams, s.near, s.far, _scene_targets(s, scale), f"targets fx·{factor:g}"
            )
        return Run(
            images,
            [scale(c) for c in cams],
            s.near,
            s.far,
            _scene_targets(s, scale),
            f"inputs+targets fx·{factor:g} (fx {cams[0].fx * factor:.3g} px)",
        )
    if case == "target_is_input":
        targets = [Target(cams[k], images[k], reference=k) for k in range(2)]
        return Run(images, cams, s.near, s.far, targets, f"targets = {pair}")
    if case == "target_behind_inputs":
        target = Target(_behind_target(s, cams), None, empty=True)
        return Run(images, cams, s.near, s.far, [target], "target behind the inputs, looking away")
    raise ValueError(f"unknown hard case {case!r}; choose from {', '.join(CASES)}")


# ---- running ------------------------------------------------------------------------------
