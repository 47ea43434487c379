"""The paper's neural field (Sec. 4.1): ``(c, f, s) = NN(x, d)``, kernel size s varying in space (Sec. 3.2).

Geometry network ``(f, 1/s, f_geo, n) = NN_geo([Psi(u), u])``, one hidden layer 31 -> 64 -> 31;
radiance network ``c = NN_rad([SH(d'), f_geo, n, u])``, 48 -> 64 -> 64 -> 3 with a sigmoid, where ``d'`` is
the view direction mirrored about the predicted normal (``view_encoding="reflected"``, Ref-NeRF's
reparametrisation: a glossy highlight is then a smooth function of ``d'`` that a surface can show, instead of
a depth-dependent colour that only a wide kernel can fake) or ``d`` itself (``"direction"``, the paper's).

Units: the field takes WORLD points ``x`` and works on ``u = (x - center) * scale``, whose domain is the cube
``[-1, 1]^3`` (the hash grid sees ``(u + 1) / 2``). Its outputs are returned in world units:
``sdf = f_unit / scale`` and ``s = s_unit / scale`` (``inv_s = inv_s_unit * scale``), so ``f / s`` (what NeuS
renders with, Eq. 3) does not depend on the scale, and ``|grad_x sdf| = |grad_u f_unit|`` (the eikonal term,
Eq. 10, has the same value in both frames). Directions are the same in both frames (the map is a
uniform scaling).

Kernel size: the network's raw output ``r`` gives ``inv_s_unit = exp(clamp(r + ln init_inv_s, ln inv_s_min,
ln inv_s_max))``, positive, equal to ``init_inv_s`` at initialisation; outside the clamp range the gradient
with respect to ``r`` is zero. With ``kernel_grid = K`` (ours), ``r`` has a second term: a trilinear K^3 grid
over the unit cube (zeros at the start). The network's ``r`` is one row of a layer whose hidden units and
hash features the SDF and colour share and dominate, so on its own s varies little from place to place (the
furry bunny's bare skin kept the kernel of its fur); the grid's entries are moved only by the losses on s,
so fur can keep a wide kernel while bare surfaces next to it sharpen.

Spatial derivatives: with the Warp encoding (the default) autograd sees ``x`` only through the MLPs' direct
``u`` input, not through the hash grid; take ``grad f`` by finite differences of :meth:`ShellField.sdf`, as
the paper does (Sec. 3.5).

The geometry network starts as a sphere (SAL / NeuS geometric initialisation): the hidden units see only
``u`` through unit directions spread evenly over the sphere, so ``f_unit(u) ~= |u| - init_radius``, and the
predicted normal starts as ``u / |u|``, the sphere's.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from ..config import FieldConfig
from .contraction import CONTRACTED_RADIUS, ContractionMap
from .hashgrid import HashGridEncoding
from .sh import N_COEFFS, spherical_harmonics

#: NeuS's geometry activation is softplus with this beta: a smooth ReLU, so finite-difference normals are
#: smooth. torch's own softplus: with denormals flushed (:func:`neural.device.flush_denormals`) its CPU
#: kernels take 11-14 ms forward and backward on (65536, 64) pre-activations of a trained lego field, where
#: an autograd Function that kept exp and log away from under- and overflow took 33 ms.
SOFTPLUS_BETA = 100.0
#: Rows the networks take at once when evaluated without autograd on a CPU (rendering): one chunk's
#: activations (a few MB) stay in the cache between the passes over them. The hash encoding still runs on
#: all rows at once (each of its launches costs a fixed overhead).
INFERENCE_CHUNK = 8192


class Geometry(NamedTuple):
    """Geometry-network outputs at N points, in world units."""

    sdf: torch.Tensor  # (N,) signed distance f
    inv_s: torch.Tensor  # (N,) inverse kernel size 1/s > 0
    feature: torch.Tensor  # (N, geo_feature_dim) latent f_geo
    normal: torch.Tensor  # (N, 3) predicted unit normal n


def fibonacci_sphere(n: int) -> torch.Tensor:
    """(n, 3) float32 unit vectors spread evenly over the sphere (spherical Fibonacci lattice)."""
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = torch.sqrt(1.0 - z * z)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1).to(torch.float32)


def _check_points(x: torch.Tensor, name: str = "x") -> None:
    if not isinstance(x, torch.Tensor) or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"{name}: expected a (N, 3) tensor, got {getattr(x, 'shape', type(x))}")


class ShellField(nn.Module):
    """NeuS-style SDF with a spatially varying kernel size and a view-dependent colour (paper Sec. 3.2, 4.1).

    ``center`` (3,) and ``scale`` map world points into the unit cube, ``u = (x - center) * scale``; both are
    buffers (saved with the weights, moved by ``.to()``).
    """

    def __init__(self, config: FieldConfig | None = None, center=(0.0, 0.0, 0.0), scale: float = 1.0):
        super().__init__()
        self.config = config or FieldConfig()
        center = torch.as_tensor(center, dtype=torch.float32)
        if center.shape != (3,) or not torch.isfinite(center).all():
            raise ValueError(f"center: expected 3 finite numbers, got {center.tolist()}")
        if not (math.isfinite(float(scale)) and float(scale) > 0):
            raise ValueError(f"scale: expected a finite number > 0, got {scale!r}")
        self.register_buffer("center", center)
        self.register_buffer("scale", torch.tensor(float(scale), dtype=torch.float32))

        cfg = self.config
        self.encoding = HashGridEncoding(cfg.hashgrid, backend=cfg.backend, cpu_threads=cfg.cpu_threads)
        self.geo_hidden = nn.Linear(self.encoding.out_dim + 3, cfg.geo_hidden)
        self.geo_out = nn.Linear(cfg.geo_hidden, 2 + cfg.geo_feature_dim + 3)
        self.rad = nn.Sequential(
            nn.Linear(N_COEFFS + cfg.geo_feature_dim + 3 + 3, cfg.rad_hidden),
            nn.ReLU(inplace=True),  # on the product just made: one pass and no new tensor (exact)
            nn.Linear(cfg.rad_hidden, cfg.rad_hidden),
            nn.ReLU(inplace=True),
            nn.Linear(cfg.rad_hidden, 3),
        )
        self.kernel_grid = None
        if cfg.kernel_grid:
            k = cfg.kernel_grid
            self.kernel_grid = nn.Parameter(torch.zeros(1, 1, k, k, k))
        self.env = None
        if cfg.env_map:
            self.env = nn.Sequential(
                nn.Linear(N_COEFFS, cfg.rad_hidden), nn.ReLU(inplace=True), nn.Linear(cfg.rad_hidden, 3)
            )
        self._sphere_init()

    @torch.no_grad()
    def _sphere_init(self) -> None:
        """f_unit(u) ~= |u| - init_radius and n(u) = u / |u| (SAL / NeuS geometric initialisation).

        Hidden unit i computes softplus(w_i . u) with unit w_i evenly spread; the average of relu(w . u)
        over the sphere is |u| / 4, hence the output weights 4 / H. The encoding's inputs start at zero
        weight (Adam moves them on the first step), as in NeuS / instant-nsr-pl.
        """
        hidden = self.config.geo_hidden
        directions = fibonacci_sphere(hidden)  # (H, 3)
        enc_dim = self.encoding.out_dim
        self.geo_hidden.weight.zero_()
        self.geo_hidden.weight[:, enc_dim:] = directions
        self.geo_hidden.bias.zero_()
        n_feat = self.config.geo_feature_dim
        self.geo_out.weight[:2].zero_()
        self.geo_out.weight[0] = 4.0 / hidden
        self.geo_out.bias[:2] = torch.tensor([-self.config.init_radius, 0.0])
        self.geo_out.weight[2 + n_feat :] = directions.T * (4.0 / hidden)
        self.geo_out.bias[2 + n_feat :] = 0.0

    @property
    def contraction(self) -> ContractionMap | None:
        """For a field in contracted space (``FieldConfig.contract``), the map of world samples into it: about
        its centre, the object's unit ball half its box (which holds the contracted ball of radius 2); None
        for a bounded field."""
        if not self.config.contract:
            return None
        return ContractionMap(self.center.detach(), 1.0 / (CONTRACTED_RADIUS * float(self.scale)))

    def to_unit(self, x: torch.Tensor) -> torch.Tensor:
        """World points x (N, 3) -> unit-space points u (N, 3) float32."""
        _check_points(x)
        return (x.to(torch.float32) - self.center) * self.scale

    def _geometry_input(self, u: torch.Tensor) -> torch.Tensor:
        """(N, L*F + 3) input ``[Psi(u), u]`` of the geometry network at unit points u (N, 3)."""
        return torch.cat([self.encoding(((u + 1.0) * 0.5).contiguous()), u], dim=1)

    def _activation(self, z: torch.Tensor) -> torch.Tensor:
        """The geometry network's softplus of hidden pre-activations z (N, H)."""
        return F.softplus(z, beta=SOFTPLUS_BETA)

    def _hidden(self, u: torch.Tensor) -> torch.Tensor:
        """(N, geo_hidden) activations of the geometry network at unit points u (N, 3)."""
        return self._activation(self.geo_hidden(self._geometry_input(u)))

    def _inference_rows(self, inp: torch.Tensor, layers) -> torch.Tensor:
        """``layers(inp)`` (N, W) for the rows of ``inp`` (N, K): :data:`INFERENCE_CHUNK` rows at a time on a
        CPU without autograd, all at once otherwise."""
        if torch.is_grad_enabled() or inp.is_cuda or len(inp) <= INFERENCE_CHUNK:
            return layers(inp)
        first = layers(inp[:INFERENCE_CHUNK])
        out = inp.new_empty(len(inp), first.shape[1])
        out[:INFERENCE_CHUNK] = first
        for i in range(INFERENCE_CHUNK, len(inp), INFERENCE_CHUNK):
            out[i : i + INFERENCE_CHUNK] = layers(inp[i : i + INFERENCE_CHUNK])
        return out

    def _geo_out(self, h: torch.Tensor) -> torch.Tensor:
        """The geometry network's output layer on hidden activations h (N, H) -> (N, 2 + geo_feature_dim + 3).
        Without autograd on a CPU its rows are padded with zeros to a multiple of 8 (MKL's product into 31
        columns takes twice as long as into 32; the columns kept are the same numbers)."""
        weight, bias = self.geo_out.weight, self.geo_out.bias
        pad = -len(weight) % 8
        if torch.is_grad_enabled() or h.is_cuda or pad == 0:
            return self.geo_out(h)
        weight = torch.cat([weight, weight.new_zeros(pad, weight.shape[1])])
        return torch.addmm(torch.cat([bias, bias.new_zeros(pad)]), h, weight.t())[:, : len(bias)]

    def geometry(self, x: torch.Tensor) -> Geometry:
        """Geometry network at world points x (N, 3) -> :class:`Geometry` in world units."""
        u = self.to_unit(x)
        out = self._inference_rows(
            self._geometry_input(u), lambda inp: self._geo_out(self._activation(self.geo_hidden(inp)))
        )
        n_feat = self.config.geo_feature_dim
        cfg = self.config
        raw = out[:, 1]
        if self.kernel_grid is not None:
            raw = raw + self._kernel_offset(u)
        log_inv_s = torch.clamp(
            raw + math.log(cfg.init_inv_s), math.log(cfg.inv_s_min), math.log(cfg.inv_s_max)
        )
        return Geometry(
            sdf=out[:, 0] / self.scale,
            inv_s=torch.exp(log_inv_s) * self.scale,
            feature=out[:, 2 : 2 + n_feat],
            normal=F.normalize(out[:, 2 + n_feat :], dim=1, eps=1e-12),
        )

    def _kernel_offset(self, u: torch.Tensor) -> torch.Tensor:
        """(N,) trilinear value of the kernel-size grid at unit points u (N, 3); 0 outside the cube."""
        grid = u.view(1, -1, 1, 1, 3)  # grid_sample's last axis is (x, y, z) = (W, H, D) of the volume
        return F.grid_sample(self.kernel_grid, grid, align_corners=True, padding_mode="zeros").view(-1)

    def radiance(self, x: torch.Tensor, d: torch.Tensor, geo: Geometry) -> torch.Tensor:
        """Colour (N, 3) in [0, 1] at world points x (N, 3) seen along directions d (N, 3) (any length)."""
        u = self.to_unit(x)
        _check_points(d, "d")
        if d.shape[0] != u.shape[0] or geo.feature.shape[0] != u.shape[0]:
            raise ValueError(
                f"d: expected {u.shape[0]} directions matching x and geo, got d {tuple(d.shape)}, "
                f"geo.feature {tuple(geo.feature.shape)}"
            )
        d = F.normalize(d.to(torch.float32), dim=1)
        if self.config.view_encoding == "reflected":
            d = d - 2.0 * (d * geo.normal).sum(1, keepdim=True) * geo.normal
        sh = spherical_harmonics(d)
        inp = torch.cat([sh, geo.feature, geo.normal, u], dim=1)
        return torch.sigmoid(self._inference_rows(inp, self.rad))

    def environment(self, d: torch.Tensor) -> torch.Tensor | None:
        """Colour (R, 3) in [0, 1] of what lies beyond the box along directions d (R, 3) (any length), from
        the environment map ``sigmoid(MLP(SH(d)))``; None for a field without one (``env_map`` false)."""
        if self.env is None:
            return None
        _check_points(d, "d")
        return torch.sigmoid(self.env(spherical_harmonics(F.normalize(d.to(torch.float32), dim=1))))

    def forward(self, x: torch.Tensor, d: torch.Tensor) -> tuple[Geometry, torch.Tensor]:
        """World points x (N, 3), directions d (N, 3) -> (:class:`Geometry`, rgb (N, 3))."""
        geo = self.geometry(x)
        return geo, self.radiance(x, d, geo)

    def sdf(self, x: torch.Tensor) -> torch.Tensor:
        """Signed distance (N,) in world units at world points x (N, 3); only f's row of the output layer."""
        h = self._hidden(self.to_unit(x))
        return (h @ self.geo_out.weight[0] + self.geo_out.bias[0]) / self.scale

    @torch.no_grad()
    def sdf_and_kernel(self, x: torch.Tensor, chunk: int = 262144) -> tuple[torch.Tensor, torch.Tensor]:
        """(sdf (N,), s (N,)) in world units at world points x (N, 3), ``chunk`` points at a time."""
        _check_points(x)
        if not isinstance(chunk, int) or chunk < 1:
            raise ValueError(f"chunk: expected a positive int, got {chunk!r}")
        sdf, s = [], []
        for start in range(0, max(x.shape[0], 1), chunk):  # one (empty) chunk when N = 0
            geo = self.geometry(x[start : start + chunk].to(self.center.device))
            sdf.append(geo.sdf)
            s.append(1.0 / geo.inv_s)
        return torch.cat(sdf), torch.cat(s)

    def config_dict(self) -> dict:
        """The field's :class:`FieldConfig` as a JSON-ready dict (centre and scale are stored apart)."""
        return self.config.to_dict()

    @classmethod
    def from_config_dict(cls, data: dict, center=(0.0, 0.0, 0.0), scale: float = 1.0) -> ShellField:
        """Rebuild an (untrained) field from :meth:`config_dict` output and the scene normalisation."""
        return cls(FieldConfig.from_dict(data), center=center, scale=scale)
