"""Slow, obviously-correct twins of the shell package's fast paths, for tests and benches only.

- :func:`evolve_level_set_reference`: :func:`neural.shell.levelset.evolve_level_set` (paper Sec. 3.3,
  Eq. 4-5, Procedure 1) by dense slicing of every interior node, with the derivatives written out one by
  one, in place of the band's gathered indices and unscaled differences.

Nothing in the library imports this module.
"""

from __future__ import annotations

import torch

from neural.shell.levelset import _EPS_GRAD2, _check_grid, soft_falloff


def evolve_level_set_reference(
    f: torch.Tensor,
    velocity: torch.Tensor,
    steps: int = 50,
    dt: float = 0.1,
    zeta: float = 0.1,
    lambda_curv: float = 0.0,
    spacing: float = 1.0,
) -> torch.Tensor:
    """Slow twin of :func:`~neural.shell.levelset.evolve_level_set`: Procedure 1 on every interior node by
    dense slicing, one Euler step per ``dt`` (no sub-steps: the caller keeps ``dt`` stable). Same arguments
    (``f``, ``velocity`` (X, Y, Z)) and result (f_T (X, Y, Z))."""
    _check_grid(f, velocity)
    h = float(spacing)
    f = f.detach().clone()
    X, Y, Z = f.shape
    v = velocity[1:-1, 1:-1, 1:-1]

    def sh(dx: int, dy: int, dz: int) -> torch.Tensor:
        return f[1 + dx : X - 1 + dx, 1 + dy : Y - 1 + dy, 1 + dz : Z - 1 + dz]

    units = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    for _ in range(steps):
        c = sh(0, 0, 0)
        plus = [sh(*e) for e in units]
        minus = [sh(*(-i for i in e)) for e in units]
        grad_out = torch.zeros_like(c)  # Godunov: max(D^-, 0)^2 + min(D^+, 0)^2, for v > 0
        grad_in = torch.zeros_like(c)  # min(D^-, 0)^2 + max(D^+, 0)^2, for v < 0
        for p, m in zip(plus, minus, strict=True):
            d_minus, d_plus = (c - m) / h, (p - c) / h
            grad_out = grad_out + d_minus.clamp(min=0) ** 2 + d_plus.clamp(max=0) ** 2
            grad_in = grad_in + d_minus.clamp(max=0) ** 2 + d_plus.clamp(min=0) ** 2
        rate = -torch.where(v > 0, v * grad_out.sqrt(), v * grad_in.sqrt())
        if lambda_curv > 0:
            fx, fy, fz = ((p - m) / (2 * h) for p, m in zip(plus, minus, strict=True))
            fxx, fyy, fzz = ((p - 2 * c + m) / h**2 for p, m in zip(plus, minus, strict=True))
            fxy = (sh(1, 1, 0) - sh(1, -1, 0) - sh(-1, 1, 0) + sh(-1, -1, 0)) / (4 * h * h)
            fxz = (sh(1, 0, 1) - sh(1, 0, -1) - sh(-1, 0, 1) + sh(-1, 0, -1)) / (4 * h * h)
            fyz = (sh(0, 1, 1) - sh(0, 1, -1) - sh(0, -1, 1) + sh(0, -1, -1)) / (4 * h * h)
            num = (
                fxx * (fy**2 + fz**2)
                + fyy * (fx**2 + fz**2)
                + fzz * (fx**2 + fy**2)
                - 2 * (fx * fy * fxy + fx * fz * fxz + fy * fz * fyz)
            )
            rate = rate + lambda_curv * num / (fx**2 + fy**2 + fz**2 + _EPS_GRAD2)
        f[1:-1, 1:-1, 1:-1] = c + dt * soft_falloff(c, zeta) * rate
    return f
