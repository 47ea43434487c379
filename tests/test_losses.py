"""neural.losses (Eq. 8-12): closed forms on the analytic sphere SDF and on linear log-kernel fields, and
float64 gradchecks."""

from __future__ import annotations

import math

import pytest
import torch

from neural.losses import (
    color_loss,
    eikonal_loss,
    finite_difference_gradient,
    kernel_sharpness_loss,
    kernel_smoothness_loss,
    normal_loss,
    total_loss,
)

RADIUS = 0.6


def sphere_sdf(x: torch.Tensor) -> torch.Tensor:
    return x.norm(dim=-1) - RADIUS


def points(n: int = 256, seed: int = 0) -> torch.Tensor:
    """(n, 3) float64 points in a shell 0.3 < |x| < 1 around the sphere (away from the kink at 0)."""
    g = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1)
    return d * (0.3 + 0.7 * torch.rand(n, 1, generator=g, dtype=torch.float64))


def exact_gradient(sdf, x: torch.Tensor) -> torch.Tensor:
    x = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(sdf(x).sum(), x)
    return grad


def test_tetrahedral_differences_of_the_sphere_sdf_give_its_unit_gradient():
    x = points()
    for eps in (1e-3, 1e-5):  # first order: the stencil's third moment does not vanish
        grad = finite_difference_gradient(sphere_sdf, x, eps)
        torch.testing.assert_close(grad, x / x.norm(dim=1, keepdim=True), atol=10 * eps, rtol=0)
    a = torch.tensor([0.3, -2.0, 1.5], dtype=torch.float64)  # exact for a linear field, whatever the step
    torch.testing.assert_close(finite_difference_gradient(lambda y: y @ a + 4.0, x, 0.1), a.expand_as(x))


@pytest.mark.parametrize("factor", [1.0, 2.0, 0.5, 3.0])
def test_eikonal_loss_of_a_scaled_sphere_sdf_is_the_squared_excess(factor):
    grad = exact_gradient(lambda y: factor * sphere_sdf(y), points())
    assert float(eikonal_loss(grad)) == pytest.approx((factor - 1.0) ** 2, abs=1e-12)
    fd = finite_difference_gradient(lambda y: factor * sphere_sdf(y), points(), 1e-6)
    assert float(eikonal_loss(fd)) == pytest.approx((factor - 1.0) ** 2, abs=1e-4)


def test_normal_loss_is_the_distance_to_the_unit_gradient_and_does_not_move_the_sdf():
    x = points()
    grad = exact_gradient(lambda y: 2.0 * sphere_sdf(y), x).requires_grad_(True)  # the norm must not matter
    radial = x / x.norm(dim=1, keepdim=True)
    tangent = torch.nn.functional.normalize(torch.cross(radial, torch.randn_like(x), dim=1), dim=1)
    assert float(normal_loss(radial, grad)) == pytest.approx(0.0, abs=1e-12)
    assert float(normal_loss(-radial, grad)) == pytest.approx(2.0)
    tangent.requires_grad_(True)
    loss = normal_loss(tangent, grad)
    assert float(loss.detach()) == pytest.approx(math.sqrt(2.0))
    loss.backward()
    assert grad.grad is None and tangent.grad.abs().sum() > 0  # the gradient is a target: normals learn


def test_kernel_smoothness_of_a_constant_kernel_is_zero():
    inv_s = torch.full((256,), 37.0, dtype=torch.float64)
    assert float(kernel_smoothness_loss(inv_s, inv_s.clone())) == 0.0
    assert float(kernel_smoothness_loss(inv_s, torch.full_like(inv_s, 37.0 * math.e))) == pytest.approx(1.0)


def test_kernel_smoothness_of_a_linear_log_kernel_field():
    """log s(x) = a.x + b: |log s(x) - log s(x + n)| = |a.n|; over n ~ N(0, eps^2) its mean is
    |a| eps sqrt(2 / pi)."""
    a, b, eps = torch.tensor([2.0, -1.0, 2.0], dtype=torch.float64), -3.0, 0.01  # |a| = 3
    x = points(200_000, seed=1)
    noise = eps * torch.randn(x.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)

    def inv_s(y):
        return torch.exp(-(y @ a + b))

    loss = kernel_smoothness_loss(inv_s(x), inv_s(x + noise))
    assert float(loss) == pytest.approx(float((noise @ a).abs().mean()), rel=1e-9)
    assert float(loss) == pytest.approx(3.0 * eps * math.sqrt(2.0 / math.pi), rel=0.01)


def test_kernel_sharpness_of_a_linear_log_kernel_field():
    """log(s / s_floor) = k x on x = -1, -1 + h, ..., 1 (2m + 1 points, h = 1/m): the relu keeps x > 0,
    whose sum is k h m (m + 1) / 2, so the mean is k (m + 1) / (2 (2m + 1))."""
    k, m, s_floor = 3.0, 1000, 0.004
    x = torch.linspace(-1.0, 1.0, 2 * m + 1, dtype=torch.float64)
    inv_s = 1.0 / (s_floor * torch.exp(k * x))
    assert float(kernel_sharpness_loss(inv_s, s_floor)) == pytest.approx(k * (m + 1) / (2 * (2 * m + 1)))
    assert float(kernel_sharpness_loss(inv_s[: m + 1], s_floor)) == pytest.approx(0.0, abs=1e-15)


def test_color_loss_and_the_weighted_sum_of_eq_8():
    color = torch.tensor([[0.0, 0.5, 1.0], [1.0, 1.0, 1.0]])
    target = torch.tensor([[0.5, 0.5, 0.5], [1.0, 0.0, 1.0]])
    assert float(color_loss(color, target)) == pytest.approx(2.0 / 6.0)
    terms = {"color": torch.tensor(1.0), "eikonal": torch.tensor(2.0), "smooth": torch.tensor(5.0)}
    assert float(total_loss(terms, {"eikonal": 0.1, "smooth": 0.01})) == pytest.approx(1.0 + 0.2 + 0.05)
    assert float(total_loss(terms, {})) == 1.0


def test_gradients_match_finite_differences():
    g = torch.Generator().manual_seed(3)

    def rand(*shape, lo=0.0):
        return (lo + torch.rand(*shape, generator=g, dtype=torch.float64)).requires_grad_(True)

    grad, normals = rand(16, 3, lo=0.2), rand(16, 3)
    assert torch.autograd.gradcheck(eikonal_loss, (grad,))
    assert torch.autograd.gradcheck(lambda n: normal_loss(n, grad.detach()), (normals,))
    inv_s, perturbed = rand(16, lo=1.0), rand(16, lo=3.0)  # perturbed > inv_s: away from the kink of |.|
    assert torch.autograd.gradcheck(kernel_smoothness_loss, (inv_s, perturbed))
    # s = 1 / inv_s in (1/2, 1): above the floor 0.1 everywhere, so every term is active
    assert torch.autograd.gradcheck(lambda i: kernel_sharpness_loss(i, 0.1), (rand(16, lo=1.0),))
    color, target = rand(8, 3), rand(8, 3)
    assert torch.autograd.gradcheck(color_loss, (color, target.detach()))
