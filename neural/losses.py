"""The training losses of Sec. 3.5 (Eq. 8-12) and the kernel-sharpness prior, as pure functions of tensors.

The training loop (:mod:`neural.train`) evaluates the field; these functions only turn the values it got
into losses. ``inv_s`` is the field's inverse kernel width ``1 / s`` (NeuS), so ``log s = -log inv_s``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

# Regular tetrahedron directions for finite-difference gradients (4 evaluations instead of 6).
_TETRA = torch.tensor([[1.0, -1.0, -1.0], [-1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, 1.0, 1.0]])


def finite_difference_gradient(
    sdf: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, eps: float
) -> torch.Tensor:
    """grad f at ``x`` (N, 3) by tetrahedral finite differences with step ``eps``: ``sdf`` maps (M, 3) ->
    (M,); returns (N, 3). Exact for a field that is linear over each stencil; first order otherwise (the
    stencil's third moment does not vanish: the error is O(eps |Hessian f|))."""
    offsets = _TETRA.to(x) * eps
    f = sdf((x[:, None, :] + offsets[None]).reshape(-1, 3)).reshape(-1, 4)
    return (f[:, :, None] * offsets[None]).sum(1) / (4.0 * eps * eps)


def color_loss(color: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Eq. 9: mean absolute error ``mean |c(r) - c_gt(r)|`` of colours (R, 3) -> scalar."""
    return (color - target).abs().mean()


def mask_loss(opacity: torch.Tensor, coverage: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of rendered opacities (R,) against the photos' alpha (R,) -> scalar (NeuS's mask
    loss): a ray through what the photo shows as empty must stay empty, whatever its colour."""
    o = opacity.clamp(1e-4, 1.0 - 1e-4)
    return -(coverage * torch.log(o) + (1.0 - coverage) * torch.log1p(-o)).mean()


def eikonal_loss(grad: torch.Tensor) -> torch.Tensor:
    """Eq. 10: ``mean (|grad f(x)| - 1)^2`` over gradients (N, 3) -> scalar."""
    return ((grad.norm(dim=-1) - 1.0) ** 2).mean()


def normal_loss(normals: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """Eq. 12: ``mean |n(x) - grad f / |grad f||`` of predicted normals (N, 3) against the SDF's gradient
    (N, 3), which is a target only (no gradient flows into it) -> scalar."""
    target = (grad / grad.norm(dim=-1).clamp_min(1e-6)[:, None]).detach()
    return (normals - target).norm(dim=-1).mean()


def kernel_smoothness_loss(inv_s: torch.Tensor, inv_s_perturbed: torch.Tensor) -> torch.Tensor:
    """Eq. 11: ``mean |log s(x) - log s(x + n)|`` from ``inv_s`` (N,) at x and ``inv_s_perturbed`` (N,) at
    x + n, n ~ N(0, eps^2) drawn by the caller -> scalar."""
    return (torch.log(inv_s) - torch.log(inv_s_perturbed)).abs().mean()


def kernel_sharpness_loss(inv_s: torch.Tensor, s_floor: float) -> torch.Tensor:
    """The kernel-sharpness prior (ours): ``mean relu(log(s / s_floor))`` over ``inv_s`` (N,) -> scalar.

    Where the images do not care how wide the kernel is (a plain glossy surface away from silhouettes),
    nothing else sets s, and Eq. 11 carries the fur's wide kernel onto the bare skin beside it; this weak
    constant pull makes such places surfaces, while content whose colour needs a volume (fur) keeps its
    kernel against it. It stops at ``s_floor``, below which the training's ray marching could not tell the
    difference: kernels narrower than it get neither loss nor gradient.
    """
    return torch.relu(-torch.log(s_floor * inv_s)).mean()


def total_loss(terms: dict[str, torch.Tensor], weights: dict[str, float]) -> torch.Tensor:
    """Eq. 8 (with the sharpness prior and the optional terms): ``L_c + sum_k weights[k] * terms[k]`` over the
    keys of ``weights`` that ``terms`` holds besides ``"color"`` (a term a step did not compute, such as the
    mask loss of photos without alpha, adds nothing)."""
    loss = terms["color"]
    for name, weight in weights.items():
        if name in terms:
            loss = loss + weight * terms[name]
    return loss
