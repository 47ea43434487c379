"""NeuS opacity with a spatially varying kernel size (paper Sec. 3.1-3.2, Eq. 3).

The SDF ``f`` is turned into opacity through the logistic CDF ``Phi_s(f) = sigmoid(f * inv_s)`` where
``inv_s = 1 / s`` is the *local* inverse kernel size predicted by the field at each sample (Sec. 3.2).
All distances (``sdf``, ``1 / inv_s``, ``deltas``) are in world units.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def _check_same_shape(**tensors: torch.Tensor) -> None:
    shapes = {name: tuple(t.shape) for name, t in tensors.items()}
    first = next(iter(shapes.values()))
    if len(first) != 1 or any(s != first for s in shapes.values()):
        raise ValueError(f"expected 1-D tensors of one length, got shapes {shapes}")


def annealed_cos(cos: torch.Tensor, cos_anneal: float = 1.0) -> torch.Tensor:
    """NeuS's annealed slope ``iter_cos`` (<= 0) of the SDF along the ray.

    ``iter_cos = -(relu(0.5 - 0.5 cos) (1 - a) + relu(-cos) a)`` with ``a = cos_anneal`` in [0, 1]: early in
    training (``a = 0``) every sample is treated as if the ray entered the surface; at ``a = 1`` the slope is
    ``min(cos, 0)``, the exact one for a unit-gradient SDF.

    cos : (S,) dot product of the unit ray direction with the unit SDF normal at each sample.
    Returns (S,).
    """
    if not 0.0 <= cos_anneal <= 1.0:
        raise ValueError(f"cos_anneal must lie in [0, 1], got {cos_anneal}")
    return -(F.relu(-cos * 0.5 + 0.5) * (1.0 - cos_anneal) + F.relu(-cos) * cos_anneal)


def neus_alpha(
    sdf: torch.Tensor,
    inv_s: torch.Tensor,
    cos: torch.Tensor,
    deltas: torch.Tensor,
    cos_anneal: float = 1.0,
    fronts: torch.Tensor | None = None,
) -> torch.Tensor:
    """Discrete NeuS opacity of each sample's section with a per-sample kernel (Eq. 3, discretised).

    The SDF at the section's ends is extrapolated from the sample with the predicted normal:
    ``f_prev = sdf - iter_cos * front`` and ``f_next = sdf + iter_cos * (delta - front)`` (see
    :func:`annealed_cos`), where ``front`` is the distance from the section start to the sample (``delta / 2``
    for a sample at the section centre; narrow-band end sections are asymmetric), and

        alpha = clamp((Phi(f_prev) - Phi(f_next)) / Phi(f_prev), 0, 1),   Phi(f) = sigmoid(f * inv_s).

    It is evaluated as ``-expm1(min(logsigmoid(f_next inv_s) - logsigmoid(f_prev inv_s), 0))``, which is
    the same number without an epsilon, stays exact deep inside the solid
    (``alpha -> 1 - exp(-inv_s |cos| delta)``) and has finite gradients everywhere. For an SDF linear along
    the ray this is exactly ``1 - exp(-integral of the density of Eq. 3 over the section)``, so a single
    sample per section is well defined.

    sdf : (S,) signed distance at the samples.
    inv_s : (S,) inverse kernel size 1/s at the samples (> 0).
    cos : (S,) dot(ray direction, predicted unit normal).
    deltas : (S,) section lengths in world units.
    cos_anneal : NeuS's cosine annealing ratio in [0, 1].
    fronts : (S,) distance from each section's start to its sample in world units; None = ``deltas / 2``.
    Returns alpha (S,) in [0, 1].
    """
    _check_same_shape(sdf=sdf, inv_s=inv_s, cos=cos, deltas=deltas)
    if fronts is None:
        fronts = deltas * 0.5
    slope = annealed_cos(cos, cos_anneal)
    log_prev = F.logsigmoid((sdf - slope * fronts) * inv_s)
    log_next = F.logsigmoid((sdf + slope * (deltas - fronts)) * inv_s)
    return -torch.expm1(torch.clamp(log_next - log_prev, max=0.0))


def neus_density(sdf: torch.Tensor, inv_s: torch.Tensor, cos: torch.Tensor | float = -1.0) -> torch.Tensor:
    """Continuous NeuS density (Eq. 3) for a unit-gradient SDF: ``sigma = max(-dPhi/dtau / Phi, 0)``.

    With ``dPhi/dtau = inv_s Phi (1 - Phi) cos`` this is ``inv_s * sigmoid(-sdf * inv_s) * relu(-cos)``.
    The default ``cos = -1`` is a ray entering along the normal, the density used by the shell's level set
    velocities (Eq. 6-7).

    sdf, inv_s : (N,) ; cos : (N,) or a float. Returns sigma (N,) in 1 / world units.
    """
    cos_t = torch.as_tensor(cos, dtype=sdf.dtype, device=sdf.device)
    return inv_s * torch.sigmoid(-sdf * inv_s) * F.relu(-cos_t)
