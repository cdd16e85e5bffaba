"""Image quality metrics: PSNR, SSIM and LPIPS (v0.1, AlexNet), all differentiable torch.

Images are float tensors ``[3, H, W]`` (one value, a scalar tensor) or ``[B, 3, H, W]``
(``[B]`` values) in [0, 1]; every metric takes an optional bool ``mask`` of valid pixels.
LPIPS needs its weights once: ``python -m prosplat.metrics.lpips_weights``.
"""

from prosplat.metrics.image import psnr, ssim
from prosplat.metrics.lpips import LPIPS, lpips

__all__ = ["LPIPS", "lpips", "psnr", "ssim"]
