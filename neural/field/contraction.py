"""Scene contraction for unbounded captures (paper Sec. 4.7, after Mip-NeRF 360 and BakedSDF): the whole space
mapped into the ball of radius 2, so that one hash grid, one kernel field and one pair of shells hold an
object and the room around it.

``contract(x) = x`` for ``|x| <= 1``, else ``(2 - 1 / |x|) x / |x|`` (Barron et al. 2022, Eq. 10), in the
capture's normalised frame (the object within the unit ball). Its inverse is ``y / (|y| (2 - |y|))`` for
``1 < |y| < 2``. Its Jacobian is the identity inside the unit ball and, outside,
``J = f(r) I + f'(r) x x^T / r`` with ``f(r) = (2 r - 1) / r^2`` and ``f'(r) = 2 (1 - r) / r^3``: it shrinks
lengths along a ray by ``|J d|`` (``d`` the unit direction), which is how sample spacing and shell widths in
contracted space carry back to the world.

Shapes: points (N, 3); Jacobians (N, 3, 3); torch tensors of any float dtype.
"""

from __future__ import annotations

import torch

#: Radius of the ball the whole space is contracted into.
CONTRACTED_RADIUS = 2.0


def contract(x: torch.Tensor) -> torch.Tensor:
    """(N, 3) contracted points of ``x`` (N, 3): inside the unit ball unchanged, outside pulled into the
    shell ``1 < |y| < 2``."""
    r = x.norm(dim=-1, keepdim=True)
    outside = r > 1.0
    safe = torch.where(outside, r, torch.ones_like(r))
    return torch.where(outside, (2.0 - 1.0 / safe) * x / safe, x)


def uncontract(y: torch.Tensor) -> torch.Tensor:
    """(N, 3) world points of contracted points ``y`` (N, 3), ``|y| < 2``: the inverse of :func:`contract`."""
    r = y.norm(dim=-1, keepdim=True)
    outside = r > 1.0
    safe = torch.where(outside, r, torch.ones_like(r))
    return torch.where(outside, y / (safe * (2.0 - safe)), y)


def contract_jacobian(x: torch.Tensor) -> torch.Tensor:
    """(N, 3, 3) Jacobian ``d contract / d x`` at ``x`` (N, 3) (module docstring)."""
    r = x.norm(dim=-1)
    outside = r > 1.0
    safe = torch.where(outside, r, torch.ones_like(r))
    f = torch.where(outside, (2.0 * safe - 1.0) / safe**2, torch.ones_like(r))
    df = torch.where(outside, 2.0 * (1.0 - safe) / safe**4, torch.zeros_like(r))  # f'(r) / r
    eye = torch.eye(3, dtype=x.dtype, device=x.device)
    return f[:, None, None] * eye + df[:, None, None] * x[:, :, None] * x[:, None, :]


def contracted_length(x: torch.Tensor, unit_dirs: torch.Tensor) -> torch.Tensor:
    """(N,) ``|J(x) d|``: the contracted length of a unit world length along ``unit_dirs`` (N, 3) at ``x``
    (N, 3); 1 inside the unit ball, ``f(r)`` across the radius and ``f(r) + r f'(r) = 1 / r^2`` along it."""
    return torch.einsum("nij,nj->ni", contract_jacobian(x), unit_dirs).norm(dim=-1)


class ContractionMap:
    """Samples of world rays carried into contracted space (a :class:`neural.render.view.RestMap`): each point
    ``x`` becomes ``contract(x)``, its unit direction ``d`` becomes ``J d / |J d|`` and a world section of
    length ``delta`` one of ``|J d| delta``, so that a field living in contracted space (its SDF, kernel and
    normals there) composites world rays exactly as the paper's contracted NeuS does. ``center`` (3,) and
    ``radius`` place the unit ball in the world: the object's ball, contracted about."""

    def __init__(self, center=(0.0, 0.0, 0.0), radius: float = 1.0):
        self.center = torch.as_tensor(center, dtype=torch.float64)
        self.radius = float(radius)

    def to_field(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) contracted points (world units about ``center``) of world points ``x`` (N, 3)."""
        center = self.center.to(x)
        return center + self.radius * contract((x - center) / self.radius)

    def to_world(self, y: torch.Tensor) -> torch.Tensor:
        """(N, 3) world points of contracted points ``y`` (N, 3) (world units about ``center``, inside the
        contracted ball of radius ``2 radius``): the inverse of :meth:`map_rays`' points."""
        center = self.center.to(y)
        return center + self.radius * uncontract((y - center) / self.radius)

    def map_rays(self, points: torch.Tensor, unit_dirs: torch.Tensor):
        """``(x_c (S, 3), d_c (S, 3) unit, stretch (S,), inside (S,) all True)`` of world samples ``points``,
        ``unit_dirs`` (S, 3); ``x_c`` in world units about ``center`` (``radius * contract((x - c) /
        radius) + c``)."""
        center = self.center.to(points)
        local = (points - center) / self.radius
        jd = torch.einsum("nij,nj->ni", contract_jacobian(local), unit_dirs)
        stretch = jd.norm(dim=-1)
        mapped = center + self.radius * contract(local)
        inside = torch.ones(len(points), dtype=torch.bool, device=points.device)
        return mapped, jd / stretch.clamp_min(1e-30)[:, None], stretch, inside
