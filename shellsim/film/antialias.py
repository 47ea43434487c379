"""Anti-aliasing: several jittered rays per pixel, averaged (a box filter over the pixel's square), everywhere
(:func:`antialiased`) or only where a pixel's neighbourhood varies (:func:`adaptive`, the frames of motions
and scenes; issue 57).

**Adaptive.** Most of a frame is flat: the inside of a ground square, the sky, a body's plain side, where
every ray of a pixel sees the same colour and more rays change nothing. :func:`adaptive` casts the first ray
of every pixel (the first offset of :func:`pixel_offsets`), then the other ``samples - 1`` only through the
pixels :func:`refine_mask` picks: those whose 3x3 neighbourhood of first rays spans more than ``threshold``
in a colour channel (edges of squares, of shadows, of bodies, texture, fur), or where some of those rays
entered a field's shells and others did not (a silhouette, even one of the ground's colour). A picked pixel
is the mean of the same rays :func:`antialiased` averages, exactly; another keeps its first ray's colour,
within about ``threshold`` of that mean where its neighbours' first rays agree.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: Seed of the sub-pixel offsets of :func:`pixel_offsets`: fixed, so a frame is the same every time.
JITTER_SEED = 0


def pixel_offsets(samples: int) -> np.ndarray:
    """(samples, 2) sub-pixel offsets (dx, dy) in pixels, in [-0.5, 0.5)^2: multi-jittered sampling (Chiu,
    Shirley and Wang 1994, its canonical arrangement): one point in each cell (a, b) of a g x h grid (g h =
    ``samples``, g the largest divisor <= sqrt(samples)) and in each of the ``samples`` columns and rows,
    ``dx + 0.5 = (a + (b + u) / h) / g``, ``dy + 0.5 = (b + (a + v) / g) / h`` with u, v uniform in [0, 1)
    drawn with :data:`JITTER_SEED`; ``samples`` = 1 is the pixel centre (0, 0)."""
    if not (isinstance(samples, int) and samples >= 1):
        raise ValueError(f"samples: expected a positive integer, got {samples!r}")
    if samples == 1:
        return np.zeros((1, 2))
    g = max(d for d in range(1, math.isqrt(samples) + 1) if samples % d == 0)
    h = samples // g
    a, b = (c.reshape(-1) for c in np.meshgrid(np.arange(g), np.arange(h), indexing="ij"))
    u, v = np.random.default_rng(JITTER_SEED).random((2, samples))
    return np.stack([(a + (b + u) / h) / g, (b + (a + v) / g) / h], -1) - 0.5


def antialiased(render, samples: int):
    """``render_one(view) -> (image, stats)`` averaging ``samples`` renders of the one-camera ``Cameras``
    ``view`` by ``render(view) -> (image (H, W, 3), stats)``, each with its principal point moved so that
    pixel (i, j) casts its ray through (j + 0.5 + dx, i + 0.5 + dy) for the offsets of
    :func:`pixel_offsets` (jittered supersampling with a box filter: a pixel approaches the mean colour
    over its square). Stats are summed over the passes (``ms``, ``<stage>_ms``, ``samples_per_pixel``:
    field samples per pixel of the frame, ``counts``). ``samples`` = 1 is ``render`` itself."""
    offsets = pixel_offsets(samples)
    if samples == 1:
        return render

    def render_one(view):
        total, stats = None, {}
        for offset in offsets:
            image, pass_stats = render(shifted(view, offset))
            total = image.astype(np.float64) if total is None else total + image
            stats = {k: stats.get(k, 0) + v for k, v in pass_stats.items()}
        return (total / samples).astype(np.float32), stats

    return render_one


#: :func:`refine_mask`'s bound on the span of colours ([0, 1], each channel) in a pixel's 3x3 neighbourhood of
#: first rays, above which the pixel gets all its rays: 4 8-bit steps. On a frame of the README's main shot
#: (512x512, 4 rays) 2/255 refines 36.2% of the pixels, 4/255 36.0%, 8/255 35.6%, 16/255 34.9% (all within
#: 46.2-46.3 dB of full supersampling): edges, texture and the distant checker span far more; 64/255 leaves
#: the ground's squares aliased (1.4% of it refined). ``bench/final_frame_bench.py`` measures it.
ADAPTIVE_THRESHOLD = 4 / 255


def refine_mask(colors: np.ndarray, entered: np.ndarray, threshold: float = ADAPTIVE_THRESHOLD) -> np.ndarray:
    """(H, W) bool: the pixels to refine given their first rays' ``colors`` (H, W, 3) and whether each
    ``entered`` (H, W) bool a field's shells: somewhere in the 3x3 neighbourhood (clipped at the border) a
    channel spans more than ``threshold``, or ``entered`` differs."""
    import torch

    def span(x: torch.Tensor) -> torch.Tensor:  # (C, H, W) -> max - min over each 3x3 neighbourhood
        pool = torch.nn.functional.max_pool2d
        return pool(x[None], 3, 1, 1)[0] + pool(-x[None], 3, 1, 1)[0]

    rgb = torch.as_tensor(np.ascontiguousarray(colors.transpose(2, 0, 1)), dtype=torch.float32)
    inside = torch.as_tensor(entered, dtype=torch.float32)[None]
    return ((span(rgb).amax(dim=0) > threshold) | (span(inside)[0] > 0)).numpy()


def adaptive(trace, samples: int, threshold: float = ADAPTIVE_THRESHOLD):
    """``render_one(view) -> (image (H, W, 3) float32, stats)`` of the one-camera ``Cameras`` ``view`` with
    ``samples`` jittered rays per pixel where :func:`refine_mask` picks it (``threshold``), one elsewhere
    (module docstring). ``trace(view, pixels=None) -> (colors (P, 3) in [0, 1], stats)`` renders the pixels
    ``pixels`` (P,) int64 (row-major; None: all) of a view, its stats with ``counts`` (P,) samples per ray
    (e.g. :meth:`shellsim.film.renderer.SceneRenderer.tracer`). Stats: the traces' summed (``ms``,
    ``<stage>_ms``), ``counts`` (H, W) samples per pixel, ``samples_per_pixel`` their mean, ``refined`` the
    share of pixels refined and ``rays_per_pixel``."""
    import torch

    offsets = pixel_offsets(samples)

    def render_one(view):
        h, w = int(view.height[0]), int(view.width[0])
        colors, stats = trace(shifted(view, offsets[0]))
        total = colors.double().cpu().numpy().reshape(h, w, 3)
        counts = np.asarray(stats["counts"]).reshape(h, w).copy()
        pixels = np.flatnonzero(refine_mask(total, counts > 0, threshold)) if samples > 1 else []
        stats = {k: v for k, v in stats.items() if k.endswith("_ms") or k == "ms"}
        if len(pixels):
            index = torch.as_tensor(pixels)
            flat = total.reshape(-1, 3)
            for offset in offsets[1:]:
                more, more_stats = trace(shifted(view, offset), index)
                flat[pixels] += more.double().cpu().numpy()
                counts.reshape(-1)[pixels] += np.asarray(more_stats["counts"])
                stats = {k: v + more_stats[k] for k, v in stats.items()}
            flat[pixels] /= samples
        stats.update(
            counts=counts,
            samples_per_pixel=float(counts.mean()),
            refined=len(pixels) / (h * w),
            rays_per_pixel=1 + (samples - 1) * len(pixels) / (h * w),
        )
        return total.astype(np.float32), stats

    return render_one


def shifted(view, offset):
    """The one-camera ``view`` whose pixel (i, j) casts its ray through (j + 0.5 + dx, i + 0.5 + dy), for
    ``offset`` (dx, dy) in pixels: its principal point moved by ``-offset`` (px + dx - cx = px - (cx - dx)).
    """
    dx, dy = offset
    return dataclasses.replace(view, cx=view.cx - dx, cy=view.cy - dy)
