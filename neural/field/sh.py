"""Real spherical harmonics of degree 0..3 (4 bands, 16 coefficients) for the view direction (paper Sec. 4.1).

Same basis, order and signs as tiny-cuda-nn's ``SphericalHarmonics`` encoding with ``degree=4``: index
``l^2 + l + m`` for ``m = -l..l``, orthonormal on the unit sphere, with the Condon-Shortley phase
(``Y_{l,m} = sqrt(2) Im Y_l^{|m|}`` for ``m < 0``, ``Y_l^0``, ``sqrt(2) Re Y_l^m`` for ``m > 0``).
"""

from __future__ import annotations

import torch

N_COEFFS = 16


def spherical_harmonics(d: torch.Tensor) -> torch.Tensor:
    """d (N, 3) unit directions -> (N, 16) real SH basis values (inputs are used as given, not normalised), a
    transposed view of a (16, N) tensor."""
    if not isinstance(d, torch.Tensor) or d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"d: expected a (N, 3) tensor of directions, got {getattr(d, 'shape', type(d))}")
    x, y, z = d.t().contiguous()  # each (N,) contiguous: the products below run on whole vectors
    xy, yz, xz = x * y, y * z, x * z
    x2, y2, z2 = x * x, y * y, z * z
    return torch.stack(
        [
            torch.full_like(x, 0.28209479177387814),
            -0.48860251190291987 * y,
            0.48860251190291987 * z,
            -0.48860251190291987 * x,
            1.0925484305920792 * xy,
            -1.0925484305920792 * yz,
            0.94617469575755997 * z2 - 0.31539156525251999,
            -1.0925484305920792 * xz,
            0.54627421529603959 * (x2 - y2),
            0.59004358992664352 * y * (-3.0 * x2 + y2),
            2.8906114426405538 * xy * z,
            0.45704579946446572 * y * (1.0 - 5.0 * z2),
            0.3731763325901154 * z * (5.0 * z2 - 3.0),
            0.45704579946446572 * x * (1.0 - 5.0 * z2),
            1.4453057213202769 * z * (x2 - y2),
            0.59004358992664352 * x * (-x2 + 3.0 * y2),
        ]
    ).t()
