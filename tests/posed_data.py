"""Small posed image sets in other tools' formats, made by the tests themselves.

Images are the analytic demo scene (:mod:`prosplat.eval.demo_scene`: spheres before a checked wall
and floor), ray-cast through each pixel, with lens distortion when asked: a pixel's ray goes
through the *undistorted* normalised coordinate, exactly as a real distorted lens maps it.
COLMAP models are written by hand here (text) and with ``struct`` (binary), independently of
the library's readers, following COLMAP's documented layout.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import torch

from prosplat.convert.blender import OPENGL_TO_OPENCV
from prosplat.convert.distortion import Distortion, undistort_points
from prosplat.core.camera import Camera
from prosplat.core.image_io import write_image
from prosplat.core.rotations import rotmat_to_qvec
from prosplat.eval.demo_scene import orbit_cameras, raycast, texture


class _LensRays:
    """Quacks like a Camera for :func:`raycast`: rays through distorted pixels."""

    def __init__(self, camera: Camera, d: Distortion | None) -> None:
        self.camera, self.d = camera, d
        self.center, self.forward = camera.center, camera.forward

    def ray_directions(self, dtype=torch.float64):
        cam = self.camera.to(dtype=torch.float64)
        uv = cam.pixel_centers(torch.float64)
        K = cam.K
        xy = torch.stack([(uv[..., 0] - K[0, 2]) / K[0, 0], (uv[..., 1] - K[1, 2]) / K[1, 1]], -1)
        if self.d is not None:
            xy = undistort_points(xy, self.d)
        pc = torch.cat([xy, torch.ones_like(xy[..., :1])], -1)  # camera-space, z = 1
        d = pc @ cam.R  # R^T pc, row-vector form
        return (d / d.norm(dim=-1, keepdim=True)).to(dtype)


def scene_image(camera: Camera, d: Distortion | None = None) -> torch.Tensor:
    """[3,H,W] image of the analytic scene as a camera with lens ``d`` sees it."""
    _, points, ident = raycast(_LensRays(camera, d))
    return texture(points, ident).permute(2, 0, 1).float().contiguous()


def scene_cameras(n: int = 5, width: int = 64, height: int = 48) -> list[Camera]:
    return orbit_cameras(n, width, height)


def scene_points(cameras: list[Camera], stride: int = 4) -> tuple[torch.Tensor, list[list[int]]]:
    """Surface points seen by each camera (every ``stride``-th pixel), and for each point the
    indices of the cameras that recorded it (its track)."""
    pts, tracks = [], []
    for i, cam in enumerate(cameras):
        _, p, _ = raycast(cam)
        p = p[::stride, ::stride].reshape(-1, 3)
        pts.append(p)
        tracks += [[i]] * len(p)
    return torch.cat(pts), tracks


_MODEL_IDS = {"PINHOLE": 1, "OPENCV": 4, "OPENCV_FISHEYE": 5}


def _params(cam: Camera, d: Distortion | None) -> tuple[str, list[float]]:
    base = [cam.fx, cam.fy, cam.cx, cam.cy]
    if d is None:
        return "PINHOLE", base
    if d.model == "fisheye":
        return "OPENCV_FISHEYE", base + [d.k1, d.k2, d.k3, d.k4]
    return "OPENCV", base + [d.k1, d.k2, d.p1, d.p2]


def write_colmap_project(
    root: Path,
    cameras: list[Camera],
    d: Distortion | None = None,
    binary: bool = False,
    points: bool = True,
) -> Path:
    """``root/images/NNN.png`` + ``root/sparse/0`` (text or binary); returns ``root``."""
    (root / "images").mkdir(parents=True)
    model = root / "sparse" / "0"
    model.mkdir(parents=True)
    names = [f"{i:03d}.png" for i in range(len(cameras))]
    for cam, name in zip(cameras, names, strict=True):
        write_image(root / "images" / name, scene_image(cam, d))
    xyz, tracks = scene_points(cameras) if points else (torch.zeros(0, 3), [])
    per_image: list[list[int]] = [[] for _ in cameras]  # point ids each image observes
    for pid, track in enumerate(tracks):
        for i in track:
            per_image[i].append(pid + 1)
    model_name, params = _params(cameras[0], d)
    if binary:
        with open(model / "cameras.bin", "wb") as fh:
            fh.write(struct.pack("<Q", len(cameras)))
            for i, cam in enumerate(cameras):
                _, p = _params(cam, d)
                fh.write(struct.pack("<iiQQ", i + 1, _MODEL_IDS[model_name], cam.width, cam.height))
                fh.write(struct.pack(f"<{len(p)}d", *p))
        with open(model / "images.bin", "wb") as fh:
            fh.write(struct.pack("<Q", len(cameras)))
            for i, (cam, name) in enumerate(zip(cameras, names, strict=True)):
                q = rotmat_to_qvec(cam.R.double()).tolist()
                t = cam.t.double().tolist()
                fh.write(struct.pack("<i4d3di", i + 1, *q, *t, i + 1))
                fh.write(name.encode() + b"\0")
                fh.write(struct.pack("<Q", len(per_image[i])))
                for pid in per_image[i]:
                    fh.write(struct.pack("<ddq", 1.0, 2.0, pid))
        with open(model / "points3D.bin", "wb") as fh:
            fh.write(struct.pack("<Q", len(xyz)))
            for pid, (p, track) in enumerate(zip(xyz.tolist(), tracks, strict=True)):
                fh.write(struct.pack("<Q3d3BdQ", pid + 1, *p, 128, 128, 128, 0.5, len(track)))
                for i in track:
                    fh.write(struct.pack("<ii", i + 1, 0))
        return root
    cam_lines, img_lines, pt_lines = ["# cameras"], ["# images"], ["# points"]
    for i, (cam, name) in enumerate(zip(cameras, names, strict=True)):
        m, p = _params(cam, d)
        cam_lines.append(f"{i + 1} {m} {cam.width} {cam.height} " + " ".join(map(repr, p)))
        q = rotmat_to_qvec(cam.R.double()).tolist()
        t = cam.t.double().tolist()
        img_lines.append(" ".join(map(repr, [i + 1, *q, *t, i + 1])) + f" {name}")
        img_lines.append(" ".join(f"1.0 2.0 {pid}" for pid in per_image[i]))
    for pid, (p, track) in enumerate(zip(xyz.tolist(), tracks, strict=True)):
        tr = " ".join(f"{i + 1} 0" for i in track)
        pt_lines.append(f"{pid + 1} {p[0]!r} {p[1]!r} {p[2]!r} 128 128 128 0.5 {tr}")
    (model / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    (model / "images.txt").write_text("\n".join(img_lines) + "\n")
    (model / "points3D.txt").write_text("\n".join(pt_lines) + "\n")
    return root


def write_transforms_set(
    root: Path,
    cameras: list[Camera],
    d: Distortion | None = None,
    per_frame: bool = False,
    rgba_alpha: torch.Tensor | None = None,
    angle_x: bool = False,
) -> Path:
    """An instant-ngp / nerfstudio / NeRF-synthetic ``transforms.json`` with images; returns it.

    ``d`` writes ``k1 k2 p1 p2`` (or fisheye ``k1-k4`` with ``camera_model``), ``per_frame``
    puts the intrinsics on each frame, ``angle_x`` writes ``camera_angle_x`` (and no size) as
    NeRF synthetic does, ``rgba_alpha [H,W]`` writes RGBA PNGs with that (straight) alpha.
    """
    import numpy as np
    import OpenImageIO as oiio

    (root / "images").mkdir(parents=True)
    cam0 = cameras[0]
    intr: dict = {"fl_x": cam0.fx, "fl_y": cam0.fy, "cx": cam0.cx, "cy": cam0.cy,
                  "w": cam0.width, "h": cam0.height}  # fmt: skip
    if angle_x:
        intr = {"camera_angle_x": 2 * math.atan(0.5 * cam0.width / cam0.fx)}
    if d is not None and d.model == "fisheye":
        intr.update(camera_model="OPENCV_FISHEYE", k1=d.k1, k2=d.k2, k3=d.k3, k4=d.k4)
    elif d is not None:
        intr.update(k1=d.k1, k2=d.k2, p1=d.p1, p2=d.p2)
    frames = []
    for i, cam in enumerate(cameras):
        img = scene_image(cam, d)
        path = root / "images" / f"{i:03d}.png"
        if rgba_alpha is None:
            write_image(path, img)
        else:
            a = rgba_alpha.float()
            arr = torch.cat([img, a[None]], 0).permute(1, 2, 0).numpy()
            arr = np.ascontiguousarray((arr * 255 + 0.5).astype(np.uint8))
            out = oiio.ImageOutput.create(str(path))
            out.open(str(path), oiio.ImageSpec(arr.shape[1], arr.shape[0], 4, oiio.UINT8))
            out.write_image(arr)
            out.close()
        c2w = cam.cam_to_world.double() @ OPENGL_TO_OPENCV.double()  # OpenGL camera-to-world
        frame = {"file_path": f"images/{i:03d}" + ("" if angle_x else ".png"),
                 "transform_matrix": c2w.tolist()}  # fmt: skip
        if per_frame:
            frame.update(intr)
        frames.append(frame)
    data = {"frames": frames} if per_frame else {**intr, "frames": frames}
    path = root / "transforms.json"
    path.write_text(json.dumps(data, indent=1))
    return path
