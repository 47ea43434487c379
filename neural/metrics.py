"""Image quality metrics on images in [0, 1]: PSNR, SSIM (Wang et al. 2004), and the LPIPS status.

SSIM follows the standard definition used by NeRF papers: Gaussian window of 11 taps with sigma 1.5,
K1 = 0.01, K2 = 0.03, data range 1, population (not sample) statistics, 'valid' filtering (no padding),
the mean of the SSIM map averaged over channels. It matches
``skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
data_range=1, channel_axis=-1)``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _as_float64(name: str, x) -> torch.Tensor:
    x = x.detach() if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if not x.is_floating_point() or x.numel() == 0:
        raise TypeError(f"{name}: expected a non-empty float image in [0, 1], got {x.dtype} {tuple(x.shape)}")
    return x.to(torch.float64)


def _pair(pred, gt) -> tuple[torch.Tensor, torch.Tensor]:
    pred, gt = _as_float64("pred", pred), _as_float64("gt", gt)
    if pred.shape != gt.shape:
        raise ValueError(f"pred, gt: shapes differ: {tuple(pred.shape)} vs {tuple(gt.shape)}")
    return pred, gt.to(pred.device)


def psnr(pred, gt) -> float:
    """Peak signal-to-noise ratio in dB of ``pred`` against ``gt`` (same shape, numpy or torch, in [0, 1]).

    ``-10 log10(mean((pred - gt)^2))`` over every element; ``inf`` for identical images.
    """
    pred, gt = _pair(pred, gt)
    mse = float(torch.mean((pred - gt) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def _gaussian_window() -> torch.Tensor:
    """(11,) float64 normalised Gaussian taps, sigma 1.5."""
    x = torch.arange(SSIM_WINDOW, dtype=torch.float64) - (SSIM_WINDOW - 1) / 2
    w = torch.exp(-(x**2) / (2 * SSIM_SIGMA**2))
    return w / w.sum()


def ssim(pred, gt) -> float:
    """Structural similarity of ``pred`` against ``gt``: (H, W) or (H, W, C) images in [0, 1].

    Both at least 11 x 11 pixels; numpy or torch, any float dtype (computed in float64).
    """
    pred, gt = _pair(pred, gt)
    if pred.ndim not in (2, 3) or min(pred.shape[:2]) < SSIM_WINDOW:
        raise ValueError(
            f"pred, gt: expected (H, W) or (H, W, C) images of at least {SSIM_WINDOW}x{SSIM_WINDOW}, "
            f"got {tuple(pred.shape)}"
        )
    if pred.ndim == 2:
        pred, gt = pred[..., None], gt[..., None]
    channels = pred.shape[-1]
    w = _gaussian_window().to(pred.device)
    kernel_y = w.view(1, 1, -1, 1).expand(channels, 1, -1, 1)
    kernel_x = w.view(1, 1, 1, -1).expand(channels, 1, 1, -1)

    def blur(img: torch.Tensor) -> torch.Tensor:  # (1, C, H, W) -> (1, C, H-10, W-10), separable, valid
        out = torch.nn.functional.conv2d(img, kernel_y, groups=channels)
        return torch.nn.functional.conv2d(out, kernel_x, groups=channels)

    x = pred.permute(2, 0, 1)[None]
    y = gt.permute(2, 0, 1)[None]
    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x**2
    var_y = blur(y * y) - mu_y**2
    cov = blur(x * y) - mu_x * mu_y
    c1, c2 = SSIM_K1**2, SSIM_K2**2  # data range 1
    ssim_map = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return float(ssim_map.mean())


def lpips_status() -> str:
    """Why LPIPS is not reported: its backbone weights cannot be obtained offline."""
    return (
        "LPIPS not computed: it needs pretrained AlexNet/VGG backbone weights, which no installable package "
        "ships (the 'lpips' package bundles only its linear heads and downloads the backbone at run time)"
    )
