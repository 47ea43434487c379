"""Constrained, regularised level-set evolution on a grid (paper Sec. 3.3, Eq. 4-5, Procedure 1).

    df/dt = omega(f) * ( -|grad f| v  +  lambda_curv |grad f| div(grad f / |grad f|) )          (Eq. 4)
    omega(f) = (1 + cos(pi clamp(f / zeta, -1, 1))) / 2                                        (Eq. 5)

``f`` is negative inside (NeuS convention), ``v`` is the outward normal speed of the level sets.

Sign of the curvature term. The paper prints ``-|grad f| (v + lambda_curv div(grad f/|grad f|))``. With
``f < 0`` inside, ``div(grad f/|grad f|)`` is the mean curvature (``2/r`` on a sphere), so that sign moves
convex parts *outward*: a backward heat equation, unstable under explicit integration and the opposite of
the smoothing regulariser the text describes. We use the mean-curvature-flow sign (convex parts move
inward), which smooths.

Discretisation, forward Euler as in Procedure 1, on a regular grid of spacing ``h``:

- motion term: first-order Godunov upwinding (Osher & Sethian 1988), one-sided differences chosen by the
  sign of ``v`` so that information flows along the characteristics;
- curvature term: central differences on the 19-point stencil,
  ``|grad f| kappa = (f_xx (f_y^2 + f_z^2) + ... - 2 f_x f_y f_xy - ...) / |grad f|^2``.

Stability: each of the ``steps`` Euler steps of length ``dt`` is split into ``n`` equal sub-steps with
``n = ceil(dt / dt_stable)``, ``dt_stable = min(cfl h / max|v|, h^2 / (6 lambda_curv))``, so any input
integrates Eq. 4 over the time ``steps * dt`` the paper prescribes. With the shell velocities of
:mod:`neural.shell.extract` at their defaults ``n = 1``: exactly Procedure 1.

Work is restricted to the band: ``omega`` vanishes for ``|f| >= zeta`` and a grid value only changes
while ``omega(f) > 0`` at that very node, so the nodes that can ever change are those with
``|f_0| < zeta``. They are gathered once as flat indices; every step reads their 6 (motion) or 18
(curvature) neighbours by index and updates them in chunks. Memory: the working copy of ``f`` plus
O(band) indices and updates plus one chunk of temporaries. The outermost layer of the grid is never
updated (it has no neighbours on one side): keep the level set one voxel inside the grid.

The slow twin, :func:`neural.shell._reference.evolve_level_set_reference` (dense slices of the whole grid),
is what the tests compare against.
"""

from __future__ import annotations

import logging
import math

import torch

log = logging.getLogger(__name__)

_EPS_GRAD2 = 1e-12  # added to |grad f|^2 in the curvature denominator (f is ~unit-gradient)


def soft_falloff(f: torch.Tensor, zeta: float) -> torch.Tensor:
    """Soft window ``omega(f) = (1 + cos(pi clamp(f/zeta, -1, 1))) / 2`` of Eq. 5 (1 at f=0, 0 for |f|>=zeta).

    f : any shape. Returns the same shape.
    """
    if not zeta > 0:
        raise ValueError(f"zeta must be > 0, got {zeta}")
    return 0.5 * (1.0 + torch.cos(math.pi * torch.clamp(f / zeta, -1.0, 1.0)))


def _check_grid(f: torch.Tensor, velocity: torch.Tensor) -> None:
    if not isinstance(f, torch.Tensor) or not isinstance(velocity, torch.Tensor):
        names = f"{type(f).__name__}, {type(velocity).__name__}"
        raise TypeError(f"f and velocity must be torch tensors, got {names}")
    if f.dim() != 3 or min(f.shape) < 3:
        raise ValueError(f"f must be a (X, Y, Z) grid with every side >= 3, got shape {tuple(f.shape)}")
    if velocity.shape != f.shape:
        raise ValueError(f"velocity must have the shape of f {tuple(f.shape)}, got {tuple(velocity.shape)}")
    if not f.is_floating_point():
        raise TypeError(f"f must be a floating-point tensor, got {f.dtype}")


def band_indices(f: torch.Tensor, zeta: float, keep: torch.Tensor | None = None) -> torch.Tensor:
    """Flat int64 indices of the interior nodes of ``f`` (X, Y, Z) with ``|f| < zeta`` (and ``keep``).

    Built one x-slab at a time so that no full-size temporary is made. keep : optional (X, Y, Z) bool.
    """
    X, Y, Z = f.shape
    parts = []
    slab = max(1, (1 << 22) // (Y * Z))
    for x0 in range(1, X - 1, slab):
        x1 = min(x0 + slab, X - 1)
        m = f[x0:x1, 1:-1, 1:-1].abs() < zeta
        if keep is not None:
            m &= keep[x0:x1, 1:-1, 1:-1]
        i, j, k = torch.nonzero(m, as_tuple=True)
        parts.append(((i + x0) * Y + (j + 1)) * Z + (k + 1))
    if not parts:
        return torch.zeros(0, dtype=torch.long, device=f.device)
    return torch.cat(parts)


def _rate(
    f_flat: torch.Tensor,
    idx: torch.Tensor,
    v: torch.Tensor,
    strides: tuple[int, int, int],
    h: float,
    zeta: float,
    lambda_curv: float,
    signs: tuple[bool, bool],
) -> torch.Tensor:
    """df/dt of Eq. 4 at the band nodes ``idx`` (C,) of the flat grid, given their velocities ``v`` (C,).

    ``signs`` says whether any velocity is > 0 / < 0 (the other Godunov branch is skipped). Differences are
    kept unscaled (multiples of h) and scaled once at the end.
    """

    def at(offset: int) -> torch.Tensor:
        return torch.index_select(f_flat, 0, idx + offset)

    c = at(0)
    nbr = [(at(st), at(-st)) for st in strides]
    # Godunov |grad f|: max(D^-, 0)^2 + min(D^+, 0)^2 where v > 0, min(D^-, 0)^2 + max(D^+, 0)^2 where v < 0.
    rate = torch.zeros_like(c)
    for sign, branch in zip((1.0, -1.0), signs, strict=True):
        if not branch:
            continue
        g2 = torch.zeros_like(c)
        for fp, fm in nbr:
            g2 += (sign * (c - fm)).clamp_(min=0).square_() + (sign * (c - fp)).clamp_(min=0).square_()
        rate -= (sign * v).clamp_(min=0).mul_(g2.sqrt_()).mul_(sign)
    rate /= h
    if lambda_curv > 0:
        # 2h f_a, h^2 f_aa and 4h^2 f_ab from central differences (19-point stencil)
        g = [fp - fm for fp, fm in nbr]
        d2 = [fp + fm - 2 * c for fp, fm in nbr]
        sq = [gi.square() for gi in g]
        num = d2[0] * (sq[1] + sq[2]) + d2[1] * (sq[0] + sq[2]) + d2[2] * (sq[0] + sq[1])
        for a, b in ((0, 1), (0, 2), (1, 2)):
            sa, sb = strides[a], strides[b]
            mixed = at(sa + sb) - at(sa - sb) - at(sb - sa) + at(-sa - sb)
            num -= 0.5 * g[a] * g[b] * mixed
        # |grad f| div(grad f / |grad f|), with the smoothing (mean-curvature-flow) sign: see module doc.
        rate += (lambda_curv / (h * h)) * num / (sq[0] + sq[1] + sq[2] + 4 * h * h * _EPS_GRAD2)
    return rate.mul_(soft_falloff(c, zeta))


def evolve_level_set(
    f: torch.Tensor,
    velocity: torch.Tensor,
    steps: int = 50,
    dt: float = 0.1,
    zeta: float = 0.1,
    lambda_curv: float = 0.0,
    spacing: float = 1.0,
    cfl: float = 0.5,
    chunk: int = 1 << 19,
) -> torch.Tensor:
    """Procedure 1: forward-Euler integration of Eq. 4 for ``steps`` steps of ``dt``.

    f : (X, Y, Z) float level-set field (negative inside), sampled at ``spacing``.
    velocity : (X, Y, Z) outward normal speed, in length (units of ``spacing``) per unit time; negative
        values move the level sets inward. Only its values in the band ``|f| < zeta`` are used.
    steps, dt : number and length of the Euler steps (paper: T = 50, dt = 0.1).
    zeta : width of the soft falloff of Eq. 5, in units of ``f``.
    lambda_curv : weight of the curvature regulariser, in length^2 per unit time.
    spacing : grid spacing h (cubic voxels).
    cfl : Courant number for the motion term; steps are sub-divided when ``dt max|v| / h > cfl``.
    chunk : band nodes processed at once (bounds the temporaries).
    Returns f_T (X, Y, Z), a new tensor on the device and dtype of ``f``.
    """
    _check_grid(f, velocity)
    if steps < 0 or dt <= 0 or spacing <= 0 or lambda_curv < 0 or not 0 < cfl <= 1 or chunk < 1:
        raise ValueError(
            "need steps >= 0, dt > 0, spacing > 0, lambda_curv >= 0, 0 < cfl <= 1, chunk >= 1; got "
            f"steps={steps}, dt={dt}, spacing={spacing}, lambda_curv={lambda_curv}, cfl={cfl}, chunk={chunk}"
        )
    out = f.detach().clone().contiguous()
    keep = None if lambda_curv > 0 else velocity != 0  # nodes with v = 0 and no curvature never move
    idx = band_indices(out, zeta, keep)
    if steps == 0 or idx.numel() == 0:
        return out
    v = velocity.detach().reshape(-1)[idx].to(out.dtype)
    h = float(spacing)
    vmax = float(v.abs().max())
    dt_motion = cfl * h / vmax if vmax > 0 else math.inf
    dt_curv = h * h / (6 * lambda_curv) if lambda_curv > 0 else math.inf
    dt_stable = min(dt_motion, dt_curv)
    n_sub = max(1, math.ceil(dt / dt_stable * (1 - 1e-5)))  # tolerate float32 rounding of v
    if n_sub > 1:
        log.info("level set: %d sub-steps per step for stability (max|v| = %.3g, h = %.3g)", n_sub, vmax, h)
    X, Y, Z = out.shape
    strides = (Y * Z, Z, 1)
    flat = out.view(-1)
    rate = torch.empty_like(v)
    signs = (bool((v > 0).any()), bool((v < 0).any()))
    tau = dt / n_sub
    for _ in range(steps * n_sub):
        for a in range(0, idx.numel(), chunk):
            rate[a : a + chunk] = _rate(
                flat, idx[a : a + chunk], v[a : a + chunk], strides, h, zeta, lambda_curv, signs
            )
        flat.index_add_(0, idx, rate, alpha=tau)
    return out
