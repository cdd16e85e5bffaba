"""PSNR and SSIM for float images ``[3, H, W]`` / ``[B, 3, H, W]`` in [0, 1].

Both are plain differentiable torch, so the same functions serve as evaluation metrics and as
training losses (``1 - ssim(...)``). Unbatched input gives a scalar tensor, batched input a
``[B]`` tensor: one value per image, never a mean over the batch, because a benchmark reports
the mean of per-image PSNRs (the usual convention) and that is not the PSNR of the batch MSE.

SSIM matches scikit-image's
``structural_similarity(a, b, channel_axis=0, data_range=1, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)`` exactly: measured differences are ~1e-16 for float64 input and
<2e-7 for float32 (the tests hold them to 1e-12 and 1e-5). scikit-image filters with ``mode='reflect'`` and then crops
``(win_size - 1) // 2 = 5`` pixels from every border before averaging, so only windows that
lie wholly inside the image count: that is a 'valid' convolution, which is what is done here
(no padding). pytorch-msssim and torchmetrics use the same 'valid' region, so their numbers
agree too.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["PSNR_MAX_DB", "SSIM_WINDOW", "psnr", "ssim"]

#: PSNR is capped here: the MSE is floored at ``data_range**2 * 10**(-PSNR_MAX_DB / 10)``.
#: Identical images then score 100 dB instead of +inf, so that a mean over a test set stays
#: finite and comparable; float32 images in [0, 1] cannot be told apart meaningfully beyond it
#: (an RMS error of 1e-5 is ~1/400 of an 8-bit step).
PSNR_MAX_DB = 100.0

#: SSIM's Gaussian window: 11 taps, sigma 1.5 (Wang et al. 2004; scikit-image's
#: ``truncate=3.5`` gives radius ``int(3.5 * 1.5 + 0.5) = 5``, the same 11 taps).
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def check_image_batch(pred: Tensor, target: Tensor, fn: str) -> tuple[Tensor, Tensor, bool]:
    """Validate a pair of images; return them as ``[B, 3, H, W]`` and whether input was batched.

    Raises ``ValueError`` naming the function, the argument and the fix, so that a wrong call
    fails where it is made rather than as a broadcasting surprise inside the metric.
    """
    for name, x in (("pred", pred), ("target", target)):
        if not isinstance(x, Tensor):
            raise ValueError(f"{fn}: {name} must be a torch.Tensor, got {type(x).__name__}")
        if x.ndim not in (3, 4):
            raise ValueError(
                f"{fn}: {name} must be [3, H, W] or [B, 3, H, W], got shape {list(x.shape)}"
            )
        if x.shape[-3] != 3:
            raise ValueError(
                f"{fn}: {name} must have 3 colour channels in dim -3 ([3, H, W] or [B, 3, H, W]), "
                f"got shape {list(x.shape)}; drop alpha with x[..., :3, :, :]"
            )
        if not x.is_floating_point():
            raise ValueError(
                f"{fn}: {name} must be a float tensor in [0, 1], got {x.dtype}; "
                "convert 8-bit images with x.float() / 255"
            )
    if pred.shape != target.shape:
        raise ValueError(
            f"{fn}: pred and target must have the same shape, got {list(pred.shape)} and "
            f"{list(target.shape)}"
        )
    if pred.device != target.device:
        raise ValueError(
            f"{fn}: pred and target are on different devices ({pred.device}, {target.device})"
        )
    for name, x in (("pred", pred), ("target", target)):
        if not bool(torch.isfinite(x).all()):
            bad = int((~torch.isfinite(x)).sum())
            raise ValueError(f"{fn}: {name} contains {bad} NaN or Inf values")
    batched = pred.ndim == 4
    if not batched:
        pred, target = pred.unsqueeze(0), target.unsqueeze(0)
    if pred.dtype != target.dtype:
        dtype = torch.promote_types(pred.dtype, target.dtype)
        pred, target = pred.to(dtype), target.to(dtype)
    return pred, target, batched


def check_mask(mask: Tensor | None, images: Tensor, batched: bool, fn: str) -> Tensor | None:
    """Validate a valid-pixel mask; return it as bool ``[B, H, W]`` on the images' device.

    ``mask`` is ``[H, W]`` (shared by every image) or, for batched images, ``[B, H, W]``.
    It must be bool so that a float weight map is never silently thresholded.
    """
    if mask is None:
        return None
    b, _, h, w = images.shape
    if not isinstance(mask, Tensor):
        raise ValueError(f"{fn}: mask must be a bool torch.Tensor, got {type(mask).__name__}")
    if mask.dtype != torch.bool:
        raise ValueError(
            f"{fn}: mask must be a bool tensor of valid pixels, got {mask.dtype}; "
            "use e.g. mask > 0.5"
        )
    allowed = [(h, w), (b, h, w)] if batched else [(h, w)]
    if tuple(mask.shape) not in allowed:
        want = " or ".join(str(list(s)) for s in allowed)
        raise ValueError(f"{fn}: mask must have shape {want}, got {list(mask.shape)}")
    mask = mask.to(images.device).expand(b, h, w)
    return mask


def check_nonempty(mask: Tensor, fn: str, where: str = "") -> None:
    """Raise when some image in the batch has no valid pixel (the mean would be 0/0)."""
    counts = mask.flatten(1).sum(dim=1)
    if bool((counts == 0).any()):
        idx = [int(i) for i in torch.nonzero(counts == 0).flatten()]
        raise ValueError(f"{fn}: mask selects no pixel{where} for image(s) {idx}")


def psnr(
    pred: Tensor, target: Tensor, mask: Tensor | None = None, data_range: float = 1.0
) -> Tensor:
    """Peak signal-to-noise ratio in dB, ``10 log10(data_range^2 / MSE)``, per image.

    Args:
        pred, target: [3, H, W] or [B, 3, H, W] float images.
        mask: optional bool [H, W] or [B, H, W]; the MSE is taken over the valid pixels only
            (all three channels of each).
        data_range: the peak value (1.0 for images in [0, 1]).

    Returns:
        Scalar tensor (unbatched) or [B]. Capped at :data:`PSNR_MAX_DB` (100 dB) so identical
        images give a finite value, never ``inf`` or NaN; the cap has zero gradient.
    """
    pred, target, batched = check_image_batch(pred, target, "psnr")
    if not (isinstance(data_range, (int, float)) and math.isfinite(data_range) and data_range > 0):
        raise ValueError(f"psnr: data_range must be a positive finite number, got {data_range!r}")
    m = check_mask(mask, pred, batched, "psnr")
    se = (pred - target).square()  # [B, 3, H, W]
    if m is None:
        mse = se.flatten(1).mean(dim=1)  # [B]
    else:
        check_nonempty(m, "psnr")
        w = m.unsqueeze(1).to(se.dtype)  # [B, 1, H, W]
        mse = (se * w).flatten(1).sum(dim=1) / (3.0 * w.flatten(1).sum(dim=1))  # [B]
    floor = data_range**2 * 10.0 ** (-PSNR_MAX_DB / 10.0)
    out = 10.0 * torch.log10(data_range**2 / mse.clamp_min(floor))  # [B]
    return out if batched else out[0]


def _gaussian_window(dtype: torch.dtype, device: torch.device) -> Tensor:
    """[11] normalised Gaussian taps, sigma 1.5, as scipy.ndimage.gaussian_filter uses."""
    r = SSIM_WINDOW // 2
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    g = torch.exp(-0.5 * (x / SSIM_SIGMA) ** 2)
    return (g / g.sum()).to(dtype=dtype, device=device)


def ssim_map(pred: Tensor, target: Tensor, data_range: float = 1.0) -> Tensor:
    """Per-pixel, per-channel SSIM over the 'valid' region: [B, 3, H, W] -> [B, 3, H-10, W-10].

    Separable 11x11 Gaussian filtering of x, y, x², y², xy (one grouped conv each way);
    population (not sample) covariances, as ``use_sample_covariance=False``. No input checks:
    call :func:`ssim` unless the inputs are known good.
    """
    b, c, h, w = pred.shape
    g = _gaussian_window(pred.dtype, pred.device)
    stack = torch.cat([pred, target, pred * pred, target * target, pred * target], dim=1)
    n = stack.shape[1]  # 5C
    kx = g.view(1, 1, 1, -1).expand(n, 1, 1, SSIM_WINDOW)
    ky = g.view(1, 1, -1, 1).expand(n, 1, SSIM_WINDOW, 1)
    filt = F.conv2d(F.conv2d(stack, kx, groups=n), ky, groups=n)  # [B, 5C, H-10, W-10]
    mu_x, mu_y, e_xx, e_yy, e_xy = filt.split(c, dim=1)
    var_x = e_xx - mu_x * mu_x
    var_y = e_yy - mu_y * mu_y
    cov = e_xy - mu_x * mu_y
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    num = (2.0 * mu_x * mu_y + c1) * (2.0 * cov + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2)
    return num / den


def ssim(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Structural similarity (Wang et al. 2004), Gaussian 11x11 window, sigma 1.5, data range 1.

    Args:
        pred, target: [3, H, W] or [B, 3, H, W] float images in [0, 1], H and W >= 11.
        mask: optional bool [H, W] or [B, H, W]. The SSIM map lives on the 'valid' region
            (5 px in from every border); it is averaged over the pixels of that region whose
            mask is true. The mask is only cropped, not eroded, so windows centred on a valid
            pixel may still see invalid pixels near the mask's edge.

    Returns:
        Scalar tensor (unbatched) or [B]: the mean over channels and valid pixels, in [-1, 1].
    """
    pred, target, batched = check_image_batch(pred, target, "ssim")
    m = check_mask(mask, pred, batched, "ssim")
    h, w = pred.shape[-2:]
    if h < SSIM_WINDOW or w < SSIM_WINDOW:
        raise ValueError(
            f"ssim: images must be at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels (the window), "
            f"got {h}x{w}"
        )
    s = ssim_map(pred, target).mean(dim=1)  # [B, H-10, W-10]
    if m is None:
        out = s.flatten(1).mean(dim=1)  # [B]
    else:
        r = SSIM_WINDOW // 2
        m = m[:, r : h - r, r : w - r]
        check_nonempty(m, "ssim", f" at least {r} px from the border")
        wgt = m.to(s.dtype)
        out = (s * wgt).flatten(1).sum(dim=1) / wgt.flatten(1).sum(dim=1)
    return out if batched else out[0]
