"""Scene folders in the renderer's format, made without Blender from the analytic demo scene."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat import Gaussians, render
from prosplat.convert.nerfstudio import Frame, write_transforms
from prosplat.core.camera import Camera
from prosplat.core.image_io import write_depth, write_image
from prosplat.eval.demo_scene import orbit_cameras, pixel_aligned_gaussians, raycast


def write_synthetic_scene(folder, size=32, n_views=5):
    """A scene folder in the renderer's format, made with the analytic demo scene."""
    cams = orbit_cameras(n_views, size, size)
    g = pixel_aligned_gaussians(cams)
    (folder / "images").mkdir(parents=True)
    (folder / "depth").mkdir()
    frames = []
    for v, cam in enumerate(cams):
        write_image(folder / "images" / f"{v:03d}.png", render(g, cam).rgb)
        depth = raycast(cam)[0].float()
        write_depth(folder / "depth" / f"{v:03d}.exr", depth)
        split = "input" if v % 2 == 0 else "target"
        extra = {
            "split": split,
            "depth_file_path": f"depth/{v:03d}.exr",
            "near": float(depth.min()),
            "far": float(depth.max()),
        }
        if split == "target":
            extra["target_kind"] = "interpolation"
        frames.append(Frame(cam, f"images/{v:03d}.png", extra))
    meta = {"near": 0.5, "far": 10.0, "seed": 1, "family": "tabletop"}
    write_transforms(folder / "transforms.json", frames, meta)
    return cams


def worker_scene(folder, size=32):
    """A 3-view synthetic scene in ``folder`` as the worker takes it: (input frames 0 and 2,
    each ``{"name", "image", "camera"}`` with a Blender camera dict, and view 1's camera dict
    as a target)."""
    from prosplat.convert.posed import camera_to_blender_dict

    cams = write_synthetic_scene(folder, size=size, n_views=3)
    frames = [{"name": f"{i:03d}", "image": str(folder / "images" / f"{i:03d}.png"),
               "camera": camera_to_blender_dict(cams[i])} for i in (0, 2)]  # fmt: skip
    return frames, camera_to_blender_dict(cams[1])


def orbit_scene_with_wrong_colours(n_views, size, inputs, noise, arc_deg=50.0):
    """``n_views`` orbit views of the analytic demo scene, their exact images and depths, and
    a start for fitting: the ``inputs``' exact pixel-aligned Gaussians with their colours
    disturbed by ``noise`` (right geometry, wrong colours: what only a fit can repair)."""
    cams = orbit_cameras(n_views, size, size, arc_deg=arc_deg)
    truth = pixel_aligned_gaussians(cams)
    images = torch.stack([render(truth, c).rgb for c in cams]).clamp(0, 1)
    depths = torch.stack([raycast(c)[0] for c in cams]).float()
    start = pixel_aligned_gaussians([cams[i] for i in inputs], seed=1)
    sh = start.sh + noise * torch.randn(start.sh.shape, generator=torch.Generator().manual_seed(0))
    start = Gaussians(start.means, start.quats, start.scales, start.opacities, sh)
    return dict(cams=cams, images=images, depths=depths, start=start)


PLANE_Z, HALF_EXTENT, SIZE, FOCAL = 3.0, 2.0, 192, 200.0
EYES = ((-0.4, 0.0, 0.0), (0.05, 0.1, 0.0), (0.4, -0.05, 0.0))  # 7-8 degrees apart at the plane


def plane_texture(seed: int = 0) -> Tensor:
    """[1,3,256,256] noise at three scales: blobs SIFT finds at every scale it looks."""
    g = torch.Generator().manual_seed(seed)
    tex = sum(
        F.interpolate(torch.randn(1, 3, n, n, generator=g), size=256, mode="bicubic") / k
        for n, k in ((8, 1.0), (32, 1.5), (96, 2.5))
    )
    return torch.sigmoid(1.5 * tex)


def textured_plane_views() -> tuple[Tensor, list[Camera]]:
    """Images [V,3,S,S] of the plane z = PLANE_Z (texture over |x|, |y| <= HALF_EXTENT) and
    their cameras: each pixel centre's ray meets the plane where its colour is sampled."""
    cams = [
        Camera.look_at(e, (0.0, 0.0, PLANE_Z), (0.0, -1.0, 0.0), FOCAL, SIZE, SIZE) for e in EYES
    ]
    tex, images = plane_texture(), []
    for cam in cams:
        rays = cam.ray_directions(torch.float64)  # [S,S,3]
        c = cam.center
        hit = c + rays * ((PLANE_Z - c[2]) / rays[..., 2:])  # [S,S,3] on the plane
        grid = (hit[..., :2] / HALF_EXTENT).float()[None]  # [1,S,S,2] in grid_sample's -1..1
        images.append(F.grid_sample(tex, grid, mode="bilinear", align_corners=False)[0])
    return torch.stack(images).clamp(0, 1), cams  # [V,3,S,S]
