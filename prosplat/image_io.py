"""Image files through OpenImageIO, in the DESIGN.md convention.

In memory an image is a float32 tensor [3, H, W] in [0, 1], display-referred sRGB (what
Blender writes to PNG with the Standard view transform). Linear EXR is converted to sRGB on
read, so every image the library sees speaks the same transfer function.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor


def linear_to_srgb(x: Tensor) -> Tensor:
    """The sRGB transfer function (IEC 61966-2-1), for linear values in [0, 1]."""
    x = x.clamp(0, 1)
    return torch.where(
        x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055
    )


def srgb_to_linear(x: Tensor) -> Tensor:
    """Inverse of :func:`linear_to_srgb`."""
    x = x.clamp(0, 1)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def read_image(path: str | os.PathLike) -> Tensor:
    """Read an image file as [3, H, W] float32 sRGB in [0, 1] (alpha dropped, grey expanded)."""
    import OpenImageIO as oiio

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"cannot read image {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    finally:
        inp.close()
    if pixels is None:
        raise ValueError(f"cannot decode image {path}: {oiio.geterror()}")
    arr = torch.from_numpy(np.ascontiguousarray(pixels, dtype=np.float32))  # [H,W,C]
    if arr.shape[2] == 1:
        arr = arr.expand(-1, -1, 3)
    img = arr[..., :3].permute(2, 0, 1).contiguous()
    if path.suffix.lower() in (".exr", ".hdr"):
        img = linear_to_srgb(img)
    return img.clamp(0, 1)


def write_image(path: str | os.PathLike, image: Tensor, overwrite: bool = False) -> Path:
    """Write [3, H, W] (or [H, W] grey) in [0, 1] as an 8-bit sRGB PNG/JPEG, atomically.

    Refuses to replace an existing file unless ``overwrite`` (nothing the user owns is lost).
    """
    import OpenImageIO as oiio

    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output folder does not exist: {path.parent}")
    img = image.detach().float().cpu()
    if img.ndim == 2:
        img = img[None].expand(3, -1, -1)
    if img.ndim != 3 or img.shape[0] != 3:
        raise ValueError(f"write_image expects [3,H,W] or [H,W], got {list(image.shape)}")
    arr = np.ascontiguousarray(
        (img.clamp(0, 1).permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8)
    )
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        raise ValueError(f"no image writer for {path.suffix!r}: {oiio.geterror()}")
    spec = oiio.ImageSpec(arr.shape[1], arr.shape[0], 3, oiio.UINT8)
    if not out.open(str(tmp), spec) or not out.write_image(arr):
        msg = out.geterror()
        out.close()
        tmp.unlink(missing_ok=True)
        raise OSError(f"writing {path} failed: {msg}")
    out.close()
    os.replace(tmp, path)
    return path


def read_depth(path: str | os.PathLike) -> Tensor:
    """Read a single-channel depth EXR as [H, W] float32 (scene units; 0 = no surface)."""
    import OpenImageIO as oiio

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"depth map not found: {path}")
    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise ValueError(f"cannot read depth map {path}: {buf.geterror()}")
    arr = buf.get_pixels(oiio.FLOAT)
    if arr is None or arr.ndim != 3:
        raise ValueError(f"cannot decode depth map {path}: {buf.geterror()}")
    depth = torch.from_numpy(np.ascontiguousarray(arr[..., 0], dtype=np.float32))
    if not torch.isfinite(depth).all() or (depth < 0).any():
        raise ValueError(
            f"depth map {path} has negative or non-finite values; 0 marks 'no surface'"
        )
    return depth


def write_depth(path: str | os.PathLike, depth: Tensor, overwrite: bool = False) -> Path:
    """Write [H, W] depth as a single-channel float32 EXR (zip compression), atomically."""
    import OpenImageIO as oiio

    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    if depth.ndim != 2:
        raise ValueError(f"write_depth expects [H,W], got {list(depth.shape)}")
    arr = np.ascontiguousarray(depth.detach().float().cpu().numpy()[..., None])
    spec = oiio.ImageSpec(arr.shape[1], arr.shape[0], 1, oiio.FLOAT)
    spec.channelnames = ("Z",)
    spec.attribute("compression", "zip")
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(), arr)
    if not buf.write(str(tmp)):
        tmp.unlink(missing_ok=True)
        raise OSError(f"writing {path} failed: {buf.geterror()}")
    os.replace(tmp, path)
    return path
