"""Camera effects on the generator's training inputs, so that clean Blender renders look more like
photographs: exposure, white balance, vignetting, optical blur, sensor noise and JPEG.

The generator trained only on noise-free renders breaks on real photos. Training gives it inputs
with these effects and keeps the targets clean: it learns to see through them, as it must on
photos. Each input view is given effects with probability ``prob``, and each effect is then on or
off on its own (:attr:`CameraEffects.each`), so views get different mixes and some stay clean.

The order follows a camera's pipeline, with the effects that multiply or convolve first
(they commute up to clamping): exposure gain, white balance, vignetting (the lens's falloff
towards the corners), optical blur, sensor noise, clamp to [0, 1], JPEG (the file the photo
ends up in). All work on the stored, gamma-encoded values, which is what the generator sees;
they are approximations of what happens in linear light, chosen for what the result looks like.

Everything random is drawn up front from a ``torch.Generator`` (:func:`draw_view_effects`), a
fixed number of draws per view, so a view's effects depend only on the generator's state and its
index: the same seed gives the same images, and one batch split over ranks gets the effects of
the undivided batch (:func:`input_camera_effects`).
"""

from __future__ import annotations

import io
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from prosplat.train.common import seeded_generator

if TYPE_CHECKING:
    from prosplat.train.generator_config import TrainConfig

#: The effects, in the order they are applied.
EFFECTS = ("exposure", "white_balance", "vignetting", "blur", "noise", "jpeg")

#: The image size (px, its longer side) the blur's sigma is given at; it scales with the size.
BLUR_REFERENCE = 128


@dataclass(frozen=True)
class CameraEffects:
    """The ranges effects are drawn from; the defaults look like phone and DSLR photos.

    Why these defaults:

    * ``exposure_stops`` 0.5: a gain of 2^U(-0.5, 0.5) = 0.71-1.41 (log-uniform) on the stored
      values: the brightness spread of auto exposure between shots of one scene, and a scene
      lit otherwise than the renders' fixed lighting. More would clip large areas.
    * ``white_balance`` 0.06: each channel x U(0.94, 1.06): auto white balance misses by a few
      percent per channel between shots (a visible, not a garish, colour cast).
    * ``vignetting`` 0.35: the corners darkened by up to 35 % (about 0.6 stop) with a cos^4-like
      falloff from the image centre: phones correct most of it, a wide-open DSLR lens leaves
      0.5-1 stop.
    * ``blur_sigma`` 1.0 px at 128 px (scaled with the size): slight defocus, lens softness and
      the demosaicing/denoising of a phone; 1 px at 128 px is the softness of a photo downsized
      from a phone's ~3000 px with a mild focus miss, not motion blur.
    * ``shot_noise`` (1e-4, 4e-3) and ``read_noise`` (5e-4, 1e-2), log-uniform: the
      Poisson-Gaussian model std = sqrt(a x + b^2) of raw-noise studies (Foi et al. 2008;
      Brooks et al. 2019 draw a in 1e-4-1.2e-2) without their highest-ISO end: at x = 0.5 the
      std is 0.007-0.045 (2-11 / 255), daylight to indoor phone photos after the phone's own
      denoising; b sets the floor in the shadows (0.1-2.5 / 255).
    * ``jpeg_quality`` 60-95: phones save at about 85-95, web and messenger copies at 60-80.
    * ``each`` 0.5: each effect is on for half the views given effects, so views see every mix,
      from one effect to all of them.
    * ``enabled``: the effects that may be drawn at all (tests take one at a time).
    """

    exposure_stops: float = 0.5
    white_balance: float = 0.06
    vignetting: float = 0.35
    blur_sigma: float = 1.0
    shot_noise: tuple[float, float] = (1e-4, 4e-3)
    read_noise: tuple[float, float] = (5e-4, 1e-2)
    jpeg_quality: tuple[int, int] = (60, 95)
    each: float = 0.5
    enabled: tuple[str, ...] = EFFECTS

    def __post_init__(self) -> None:
        unknown = set(self.enabled) - set(EFFECTS)
        if unknown:
            raise ValueError(f"unknown camera effects {sorted(unknown)}; known: {list(EFFECTS)}")
        if not 0 <= self.each <= 1:
            raise ValueError(f"each is a probability in [0, 1], got {self.each}")
        lo, hi = self.jpeg_quality
        if not 1 <= lo <= hi <= 100:
            raise ValueError(f"jpeg_quality must be 1 <= low <= high <= 100, got {(lo, hi)}")
        for name in ("shot_noise", "read_noise"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must be 0 < low <= high, got {(lo, hi)}")


@dataclass(frozen=True)
class ViewEffects:
    """The effects drawn for one view; each at its neutral value when off."""

    gain: float = 1.0  # exposure: all channels x gain
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # per-channel gains
    vignetting: float = 0.0  # how much darker the corners get (0-1)
    blur: float = 0.0  # Gaussian sigma in px at BLUR_REFERENCE px (scaled with the size)
    noise: tuple[float, float] | None = None  # (a, b): std = sqrt(a x + b^2)
    noise_seed: int = 0  # seeds the noise, drawn with the rest
    jpeg: int | None = None  # JPEG quality


#: uniform numbers drawn per view (always all of them, so view k's draws never depend on
#: another view's): 1 apply + 6 on/off + 1 gain + 3 white balance + 1 vignetting + 1 blur
#: + 2 noise + 1 quality
_DRAWS = 16


def _log_uniform(u: float, lo: float, hi: float) -> float:
    return math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))


def draw_view_effects(
    n: int, generator: torch.Generator, prob: float, effects: CameraEffects
) -> list[ViewEffects | None]:
    """The effects of ``n`` views (None: a view left as it is), from ``generator`` (CPU)."""
    if not 0 <= prob <= 1:
        raise ValueError(f"prob must be in [0, 1], got {prob}")
    u = torch.rand(n, _DRAWS, generator=generator, dtype=torch.float64).tolist()  # [n,16]
    seeds = torch.randint(0, 2**62, (n,), generator=generator).tolist()  # [n]
    views: list[ViewEffects | None] = []
    e = effects
    for row, seed in zip(u, seeds):
        if not row[0] < prob:
            views.append(None)
            continue
        on = {name: row[1 + k] < e.each and name in e.enabled for k, name in enumerate(EFFECTS)}
        gain = 2.0 ** (e.exposure_stops * (2 * row[7] - 1)) if on["exposure"] else 1.0
        wb = (1.0, 1.0, 1.0)
        if on["white_balance"]:
            wb = tuple(1.0 + e.white_balance * (2 * row[8 + c] - 1) for c in range(3))
        noise = None
        if on["noise"]:
            noise = (_log_uniform(row[13], *e.shot_noise), _log_uniform(row[14], *e.read_noise))
        q_lo, q_hi = e.jpeg_quality
        views.append(
            ViewEffects(
                gain=gain,
                white_balance=wb,  # type: ignore[arg-type]
                vignetting=e.vignetting * row[11] if on["vignetting"] else 0.0,
                blur=e.blur_sigma * row[12] if on["blur"] else 0.0,
                noise=noise,
                noise_seed=int(seed),
                jpeg=q_lo + min(int(row[15] * (q_hi - q_lo + 1)), q_hi - q_lo)
                if on["jpeg"]
                else None,
            )
        )
    return views


def vignette_map(h: int, w: int, strength: float, device=None, dtype=None) -> Tensor:
    """[H,W] factor: 1 at the centre (the principal point of the renders), ``1 - strength`` in
    the corners, falling off like cos^4 of the angle to the axis of a lens whose corner ray is
    at 45 degrees, rescaled so the corner gets exactly ``1 - strength``."""
    ys = torch.arange(h, device=device, dtype=torch.float32) + 0.5 - h / 2  # [H] pixel centres
    xs = torch.arange(w, device=device, dtype=torch.float32) + 0.5 - w / 2  # [W]
    r2 = (ys[:, None] ** 2 + xs[None] ** 2) / ((h / 2) ** 2 + (w / 2) ** 2)  # [H,W], corner 1
    cos4 = 1.0 / (1.0 + r2) ** 2  # cos^4(atan r): 1 at the centre, 1/4 in the corners
    out = 1.0 - strength * (1.0 - cos4) / 0.75
    return out.to(dtype or torch.float32)


def gaussian_blur(image: Tensor, sigma: float) -> Tensor:
    """[C,H,W] blurred by a Gaussian of ``sigma`` px (separable, edges reflected)."""
    if sigma <= 0:
        return image
    r = max(1, math.ceil(3 * sigma))
    x = torch.arange(-r, r + 1, device=image.device, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = (k / k.sum()).to(image.dtype)  # [2r+1]
    c = image.shape[0]
    y = F.pad(image[None], (r, r, r, r), mode="reflect")  # [1,C,H+2r,W+2r]
    y = F.conv2d(y, k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)  # along rows
    y = F.conv2d(y, k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)  # along columns
    return y[0]


def _jpeg_bytes(hwc: np.ndarray, quality: int) -> np.ndarray:
    """[H,W,3] uint8 saved as a JPEG of ``quality`` (Pillow, 4:2:0 as cameras do) and read back."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(hwc).save(buf, format="JPEG", quality=int(quality))
    buf.seek(0)
    return np.asarray(Image.open(buf).convert("RGB"), dtype=np.uint8).copy()


def _jpeg_many(images: Tensor, qualities: list[int]) -> Tensor:
    """[N,3,H,W] in [0, 1], view i through a JPEG of qualities[i]: one copy to the CPU and
    back, the views encoded on a few threads (Pillow lets go of the GIL while it codes)."""
    hwc = (images.detach().float().clamp(0, 1) * 255).round().byte().permute(0, 2, 3, 1)
    arrays = hwc.cpu().numpy()  # [N,H,W,3]
    if len(qualities) == 1:
        back = [_jpeg_bytes(arrays[0], qualities[0])]
    else:
        workers = min(len(qualities), os.cpu_count() or 1, 8)
        with ThreadPoolExecutor(workers) as pool:
            back = list(pool.map(_jpeg_bytes, arrays, qualities))
    out = torch.from_numpy(np.stack(back)).permute(0, 3, 1, 2).float() / 255  # [N,3,H,W]
    return out.to(device=images.device, dtype=images.dtype)


def jpeg_round_trip(image: Tensor, quality: int) -> Tensor:
    """[3,H,W] in [0, 1] saved as a JPEG of ``quality`` (Pillow, 4:2:0 as cameras do) and read
    back, on the image's device and dtype."""
    return _jpeg_many(image[None], [quality])[0]


def _before_jpeg(image: Tensor, view: ViewEffects) -> Tensor:
    """One view [3,H,W] with ``view``'s effects up to the clamp (all but the JPEG)."""
    h, w = image.shape[-2:]
    x = image
    gains = [view.gain * c for c in view.white_balance]
    if any(g != 1.0 for g in gains):
        x = x * torch.tensor(gains, device=x.device, dtype=x.dtype)[:, None, None]
    if view.vignetting > 0:
        x = x * vignette_map(h, w, view.vignetting, x.device, x.dtype)
    if view.blur > 0:
        x = gaussian_blur(x, view.blur * max(h, w) / BLUR_REFERENCE)
    if view.noise is not None:
        a, b = view.noise
        g = torch.Generator(device=x.device).manual_seed(view.noise_seed)
        z = torch.randn(x.shape, generator=g, device=x.device, dtype=x.dtype)  # [3,H,W]
        x = x + z * (a * x.clamp(min=0) + b * b).sqrt()
    return x.clamp(0, 1)


def apply_view_effects(image: Tensor, view: ViewEffects) -> Tensor:
    """One view [3,H,W] in [0, 1] with ``view``'s effects, in the module's order."""
    x = _before_jpeg(image, view)
    return x if view.jpeg is None else jpeg_round_trip(x, view.jpeg)


def apply_camera_effects(
    images: Tensor, generator: torch.Generator, prob: float, effects: CameraEffects
) -> Tensor:
    """Images [V,3,H,W] or [B,V,3,H,W] in [0, 1], each view given camera effects with
    probability ``prob`` (drawn from ``generator``, a CPU generator); same shape, dtype and
    device. ``prob`` 0 returns ``images`` itself."""
    if prob == 0:
        return images
    flat = images.reshape(-1, *images.shape[-3:])  # [N,3,H,W]
    views = draw_view_effects(flat.shape[0], generator, prob, effects)
    return _apply(flat, views).view(images.shape)


def _apply(flat: Tensor, views: list[ViewEffects | None]) -> Tensor:
    """[N,3,H,W] with views[i]'s effects on view i (None: unchanged)."""
    if all(v is None for v in views):
        return flat
    out = torch.stack([x if v is None else _before_jpeg(x, v) for x, v in zip(flat, views)])
    jpeg = [i for i, v in enumerate(views) if v is not None and v.jpeg is not None]
    if jpeg:  # the JPEG views together: one trip to the CPU (Pillow) and back
        out[jpeg] = _jpeg_many(out[jpeg], [views[i].jpeg for i in jpeg])  # type: ignore[misc]
    return out


def input_camera_effects(
    batch: dict[str, Tensor],
    cfg: TrainConfig,
    step: int,
    rank: int = 0,
    world_size: int = 1,
    effects: CameraEffects | None = None,
) -> dict[str, Tensor]:
    """The batch with camera effects on its ``input_images`` [B,V,3,H,W] (``cfg.camera_effects``
    of the views), everything else (the targets above all: the clean truth) as it was.

    The effects are drawn for the global batch of ``world_size`` ranks and this rank takes its
    slice, so K processes get the effects one process with K times the batch would."""
    if cfg.camera_effects == 0:
        return batch
    images = batch["input_images"]  # [B,V,3,H,W]
    flat = images.reshape(-1, *images.shape[-3:])  # [B*V,3,H,W]
    n = flat.shape[0]
    views = draw_view_effects(
        n * world_size,
        seeded_generator(f"prosplat-camera/{cfg.seed}/{step}"),
        cfg.camera_effects,
        effects or CameraEffects(),
    )
    out = dict(batch)
    out["input_images"] = _apply(flat, views[rank * n : (rank + 1) * n]).view(images.shape)
    return out
