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


def _read_pixels(path: Path, unassociated: bool) -> tuple[Tensor, bool]:
    """[H,W,C] float32 pixels of a file (8/16-bit integers scaled to [0, 1] by OpenImageIO)
    and whether its colour is straight (unassociated) alpha."""
    import OpenImageIO as oiio

    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    config = oiio.ImageSpec()
    if unassociated:
        config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise ValueError(f"cannot read image {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        straight = bool(spec.get_int_attribute("oiio:UnassociatedAlpha", 0))
    finally:
        inp.close()
    if pixels is None:
        raise ValueError(f"cannot decode image {path}: {oiio.geterror()}")
    arr = torch.from_numpy(np.ascontiguousarray(pixels, dtype=np.float32))
    if arr.ndim == 2:
        arr = arr[..., None]
    return arr, straight


def _to_display(img: Tensor, path: Path) -> Tensor:
    if path.suffix.lower() in (".exr", ".hdr"):
        img = linear_to_srgb(img)
    return img.clamp(0, 1)


def read_image(path: str | os.PathLike) -> Tensor:
    """Read an image file as [3, H, W] float32 sRGB in [0, 1] (alpha dropped, grey expanded).

    8- and 16-bit files are scaled by their full range (255, 65535). Colour with alpha comes
    premultiplied (OpenImageIO's default), i.e. composited over black; to choose the
    background use :func:`read_image_rgba` and :func:`composite`.
    """
    path = Path(path)
    arr, _ = _read_pixels(path, unassociated=False)
    if arr.shape[2] == 1:
        arr = arr.expand(-1, -1, 3)
    return _to_display(arr[..., :3].permute(2, 0, 1).contiguous(), path)


def read_image_rgba(path: str | os.PathLike) -> tuple[Tensor, Tensor | None]:
    """Read an image as ``(rgb [3,H,W], alpha [H,W] or None)``, float32 in [0, 1], with
    ``rgb`` *premultiplied* by alpha (straight-alpha PNGs are multiplied here, in the file's
    sRGB values, the convention of NeRF-synthetic data). ``alpha`` is None without an alpha
    channel (RGB, grey) and for images whose alpha is 1 everywhere."""
    path = Path(path)
    arr, straight = _read_pixels(path, unassociated=True)
    c = arr.shape[2]
    if c in (1, 2):  # grey, grey + alpha
        arr = torch.cat([arr[..., :1].expand(-1, -1, 3), arr[..., 1:]], dim=2)
        c = arr.shape[2]
    rgb = arr[..., :3].permute(2, 0, 1).contiguous()
    alpha = arr[..., 3].clamp(0, 1) if c >= 4 else None
    if alpha is not None and straight:
        rgb = rgb * alpha
    rgb = _to_display(rgb, path)
    if alpha is not None and bool((alpha >= 1).all()):
        alpha = None
    return rgb, alpha


def composite(rgb: Tensor, alpha: Tensor | None, background: Tensor) -> Tensor:
    """Premultiplied ``rgb [3,H,W]`` with ``alpha [H,W]`` over a ``background [3]`` colour in
    [0, 1]: ``rgb + (1 - alpha)·background`` (``rgb`` itself when alpha is None)."""
    if alpha is None:
        return rgb
    bg = torch.as_tensor(background, dtype=rgb.dtype).reshape(3, 1, 1)
    return (rgb + (1 - alpha)[None] * bg).clamp(0, 1)


def check_images(images, name: str = "images") -> None:
    """Raise ``ValueError`` unless ``images`` is a float tensor with finite values in [0, 1].

    The message names the fix: 8-bit tensors (uint8, or floats 0-255) must be divided by 255;
    files should go through :func:`read_image`, which scales 8- and 16-bit data itself.
    """
    if not isinstance(images, Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(images).__name__}")
    if not images.is_floating_point():
        raise ValueError(
            f"{name} must be a float tensor in [0, 1], got {images.dtype}; convert 8-bit images "
            "with images.float() / 255 (or read files with prosplat.core.image_io.read_image)"
        )
    if images.numel() == 0:
        return
    if not bool(torch.isfinite(images).all()):
        raise ValueError(f"{name} contain NaN or Inf values; images must be finite, in [0, 1]")
    lo, hi = float(images.min()), float(images.max())
    if lo < -1e-3 or hi > 1 + 1e-3:
        hint = (
            "they look like 0-255 values: divide by 255"
            if hi > 1.5
            else "clamp them with images.clamp(0, 1)"
        )
        raise ValueError(
            f"{name} must be in [0, 1] (display-referred sRGB), got values in [{lo:.4g}, "
            f"{hi:.4g}]; {hint}"
        )


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
