import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from neural.metrics import psnr, ssim


@pytest.mark.parametrize("error", [0.5, 0.1, 0.01, 1e-3])
def test_psnr_of_a_constant_error_is_closed_form(rng, error):
    gt = rng.uniform(0.2, 0.7, size=(9, 7, 3))
    sign = rng.choice([-1.0, 1.0], size=gt.shape)
    expected = -10 * math.log10(error**2)
    assert psnr(gt + sign * error, gt) == pytest.approx(expected, abs=1e-9)
    pred = torch.tensor(gt + error, dtype=torch.float32)
    assert psnr(pred, torch.tensor(gt)) == pytest.approx(expected, abs=1e-4)


def test_psnr_of_identical_images_is_infinite(rng):
    x = rng.uniform(size=(4, 4, 3))
    assert psnr(x, x) == math.inf


def test_psnr_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="pred, gt"):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


def _skimage_ssim(x, y):
    kwargs = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0)
    if x.ndim == 3:
        kwargs["channel_axis"] = -1
    return structural_similarity(x, y, **kwargs)


@pytest.mark.parametrize("shape", [(32, 40, 3), (24, 24), (11, 17, 1)])
def test_ssim_matches_skimage_on_random_images(rng, shape):
    x = rng.uniform(size=shape)
    y = rng.uniform(size=shape)
    assert ssim(x, y) == pytest.approx(_skimage_ssim(x, y), abs=1e-10)


def test_ssim_matches_skimage_on_correlated_images(rng):
    gt = rng.uniform(size=(48, 36, 3))
    pred = np.clip(gt + rng.normal(scale=0.05, size=gt.shape), 0, 1)
    value = ssim(pred, gt)
    assert 0.5 < value < 1.0
    assert value == pytest.approx(_skimage_ssim(pred, gt), abs=1e-10)
    torch_value = ssim(torch.tensor(pred, dtype=torch.float32), torch.tensor(gt, dtype=torch.float32))
    assert torch_value == pytest.approx(value, abs=1e-6)


def test_ssim_of_an_image_with_itself_is_one(rng):
    x = rng.uniform(size=(20, 30, 3))
    assert ssim(x, x) == pytest.approx(1.0, abs=1e-12)


def test_ssim_rejects_images_smaller_than_the_window():
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((10, 20, 3)), np.zeros((10, 20, 3)))
