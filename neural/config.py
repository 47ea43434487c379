"""The settings of the library's stages, in one light module (stdlib only) so that the command line can show
their defaults without importing torch: the field (:class:`FieldConfig`, :class:`HashGridConfig`), the two
training stages, the shell extraction (:class:`ShellConfig`), the narrow-band sampler
(:class:`NarrowBandConfig`) and Procedure 4 end to end (:class:`PipelineConfig`). :mod:`neural.field`,
:mod:`neural.train`, :mod:`neural.shell`, :mod:`neural.render.narrowband` and :mod:`neural.pipeline` import
them from here.

Each config checks its values on construction and raises :class:`ConfigError`, which names the field and
what it takes: every bound is written here once, and ``shellsim``'s job settings that set these fields
report it as theirs.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import asdict, dataclass, field, fields, replace

from .errors import InputError

BACKENDS = ("warp", "torch")  # implementations of the hash encoding
#: Where a field lives: "contracted" for photos without alpha (the room around the object), else "bounded";
#: or either one whatever the photos.
SPACES = ("auto", "bounded", "contracted")
VIEW_ENCODINGS = ("reflected", "direction")
# Fields written before these settings existed had neither: absent from a file, they mean the paper's.
LEGACY_DEFAULTS = {"view_encoding": "direction", "kernel_grid": 0, "contract": False}
MAX_SEED = 2**31 - 1  # seeds of the training stages lie in [0, MAX_SEED]
MAX_KERNEL_GRID = 512  # nodes per axis of the kernel-size grid at most (512^3 values, 0.5 GB)


class ConfigError(ValueError):
    """A config's field is out of its domain: ``config`` (the class), ``field`` (its name), ``expected`` (what
    it takes, e.g. "an integer >= 1") and ``value`` (what it got)."""

    def __init__(self, config: type, field: str, expected: str, value):
        self.config, self.field, self.expected, self.value = config, field, expected, value
        super().__init__(f"{config.__name__}.{field}: expected {expected}, got {value!r}")


def _plain(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def _check(config, low, high, *names: str, integer: bool = False, what: str = "", ends: str = "[]") -> None:
    """:class:`ConfigError` unless each field ``names`` of ``config`` is an integer (``integer``) or a real
    number (bools are neither) in ``[low, high]`` (``ends`` "(]", "[)" or "()" excludes an end; ``high`` inf:
    any finite number); ``what`` names the kind in the message (default "an integer" or "a number")."""
    kind = numbers.Integral if integer else numbers.Real
    what = what or ("an integer" if integer else "a number")
    for name in names:
        value = getattr(config, name)
        if isinstance(value, kind) and not isinstance(value, bool):
            above = value > low if ends[0] == "(" else value >= low
            below = value < high if ends[1] == ")" or high == math.inf else value <= high
            if above and below:
                continue
        if high == math.inf:
            expected = f"{what} {'>' if ends[0] == '(' else '>='} {_plain(low)}"
        else:
            expected = f"{what} in {ends[0]}{_plain(low)}, {_plain(high)}{ends[1]}"
        raise ConfigError(type(config), name, expected, value)


def _check_choice(config, name: str, choices) -> None:
    """:class:`ConfigError` unless the field ``name`` of ``config`` is one of ``choices``."""
    if getattr(config, name) not in choices:
        raise ConfigError(type(config), name, f"one of {', '.join(map(str, choices))}", getattr(config, name))


def _check_bool(config, *names: str) -> None:
    """:class:`ConfigError` unless each field ``names`` of ``config`` is true or false."""
    for name in names:
        if not isinstance(getattr(config, name), bool):
            raise ConfigError(type(config), name, "true or false", getattr(config, name))


@dataclass(frozen=True)
class HashGridConfig:
    """Hash-grid settings. Paper (Sec. 4.1): 14 levels of 2-D features, 2^22 entries, 16^3 -> 4096^3.

    The defaults keep the paper's levels and features and shrink table (2^17: a 15 MB field, quick Adam
    steps, enough for 200x200 NeRF-synthetic views) and finest resolution so that training on a CPU stays
    practical.
    """

    n_levels: int = 14
    n_features_per_level: int = 2
    log2_table_size: int = 17
    base_resolution: int = 16
    max_resolution: int = 2048

    def __post_init__(self):
        _check(self, 1, math.inf, "n_levels", "n_features_per_level", "base_resolution", integer=True)
        _check(self, 1, 30, "log2_table_size", integer=True)
        _check(self, self.base_resolution, math.inf, "max_resolution", integer=True)

    @property
    def table_size(self) -> int:
        """T, the number of entries per level."""
        return 1 << self.log2_table_size

    @property
    def out_dim(self) -> int:
        """L * F, the width of the encoding."""
        return self.n_levels * self.n_features_per_level

    def resolutions(self) -> list[int]:
        """``N_l = floor(base * b^l)`` for every level (the last one is ``max_resolution``)."""
        if self.n_levels == 1:
            return [self.base_resolution]
        growth = (math.log(self.max_resolution) - math.log(self.base_resolution)) / (self.n_levels - 1)
        # the small offset keeps floor() from losing the last level to round-off (e.g. 2047.9999...)
        return [
            int(math.floor(self.base_resolution * math.exp(level * growth) + 1e-6))
            for level in range(self.n_levels)
        ]


@dataclass(frozen=True)
class FieldConfig:
    """Field settings; network sizes are the paper's (Sec. 4.1), lengths are in unit space."""

    hashgrid: HashGridConfig = field(default_factory=HashGridConfig)
    geo_hidden: int = 64
    rad_hidden: int = 64
    geo_feature_dim: int = 26
    init_radius: float = 0.5
    init_inv_s: float = 20.0
    inv_s_min: float = 1.0
    inv_s_max: float = 1e5
    backend: str = "warp"
    cpu_threads: int = 2
    env_map: bool = False  # learn the colour of rays that leave the box, by direction (real captures)
    contract: bool = False  # live in contracted space, the world in the box (neural.field.contraction)
    view_encoding: str = "reflected"  # SH of d mirrored about n; "direction": SH(d), the paper's
    kernel_grid: int = 64  # nodes per axis of the kernel-size grid (see ShellField); 0: none, the paper's

    def __post_init__(self):
        if not isinstance(self.hashgrid, HashGridConfig):
            raise ConfigError(FieldConfig, "hashgrid", "a HashGridConfig", self.hashgrid)
        _check(self, 1, math.inf, "geo_hidden", "rad_hidden", "geo_feature_dim", "cpu_threads", integer=True)
        _check(self, 0, 1, "init_radius", ends="()")
        _check(self, 0, math.inf, "inv_s_min", ends="()")
        _check(self, self.inv_s_min, math.inf, "inv_s_max")
        _check(self, self.inv_s_min, self.inv_s_max, "init_inv_s")
        _check_choice(self, "backend", BACKENDS)
        if type(self.kernel_grid) is not int or self.kernel_grid != 0:  # 0: no grid
            _check(self, 2, MAX_KERNEL_GRID, "kernel_grid", integer=True, what="0 or an integer")
        _check_choice(self, "view_encoding", VIEW_ENCODINGS)
        _check_bool(self, "env_map", "contract")

    def to_dict(self) -> dict:
        """Plain JSON-ready dict (the hash grid as a nested dict)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> FieldConfig:
        """Inverse of :meth:`to_dict`; unknown or malformed entries raise :class:`InputError`."""
        if not isinstance(data, dict):
            raise InputError(f"field config: expected a JSON object, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputError(f"field config: unknown keys {unknown} (known: {sorted(known)})")
        values = {**LEGACY_DEFAULTS, **data}
        if "hashgrid" in values:
            grid = values["hashgrid"]
            grid_known = {f.name for f in fields(HashGridConfig)}
            if not isinstance(grid, dict) or set(grid) - grid_known:
                raise InputError(f"field config: hashgrid must be an object with keys {sorted(grid_known)}")
        try:
            if "hashgrid" in values:
                values["hashgrid"] = HashGridConfig(**values["hashgrid"])
            return cls(**values)
        except (TypeError, ValueError) as err:
            raise InputError(f"field config: {err}") from None


@dataclass
class Stage1Config:
    """Stage-1 settings. Loss weights are the paper's (Sec. 3.5); lengths are in the field's unit space."""

    steps: int = 6000
    target_samples: int = 65536  # gradient samples per batch (visible ones); the ray count adapts to it
    min_transmittance: float = 1e-4  # samples behind this transmittance are dropped before the gradient pass
    max_candidates: int = 196608  # samples per batch of that geometry-only pass; the ray count obeys both
    initial_rays: int = 2048
    max_rays: int = 16384
    lr_encoding: float = 3e-2  # ~3x Instant-NGP's 1e-2 / 3e-3: lego +1.3 dB after 5000 steps (white bg)
    lr_network: float = 1e-2
    warmup_steps: int = 100
    final_lr_factor: float = 0.1
    lambda_e: float = 0.1  # Eq. 10
    lambda_n: float = 0.1  # Eq. 12
    lambda_s: float = 0.01  # Eq. 11
    lambda_k: float = 0.001  # kernel sharpness prior (ours, see regularisers); 0 gives the paper's Eq. 8
    sharp_floor: float = 1.0 / 8.0  # the prior stops at s = sharp_floor * step_size
    reg_fraction: float = 0.125  # fraction of samples that the regularisers are evaluated on
    fd_eps: float = 2.0 / 1024  # finite-difference step for grad f (unit space)
    smooth_eps: float = 0.01  # std of the perturbation in Eq. 11 (unit space)
    cos_anneal_steps: int = 500  # NeuS cosine annealing
    step_size: float = 2.0 * math.sqrt(3.0) / 512  # ray-marching step (unit space)
    max_samples_per_ray: int = 1024
    occupancy_resolution: int = 128
    occupancy_every: int = 16
    random_background: bool = False  # see PixelSampler; only for images with alpha
    error_sampling: float = 0.0  # share of the rays drawn where the running error is high (see PixelSampler)
    error_tile: int = 16  # pixels per side of the tiles whose error PixelSampler keeps
    lambda_mask: float = 0.1  # opacity against the photos' alpha (binary cross-entropy; NeuS's mask loss)
    # the prior for unseen space (neural.visibility): measured every visibility_every steps from that step on
    # (at once when continuing a field); 0 weights leave it off
    lambda_carve: float = 1.0
    lambda_paint: float = 0.1
    prior_points: int = 4096  # points drawn per step for each of the two terms
    visibility_every: int = 2000
    eval_every: int = 1000
    eval_views: int = 2  # held-out views of the periodic evaluations (0: all); the final one uses all
    checkpoint_every: int = 250
    checkpoint_seconds: float = 120.0  # also checkpoint when this much time passed since the last one
    seed: int = 0

    def __post_init__(self):
        _check_stage(self)
        counts = ("target_samples", "max_candidates", "initial_rays", "max_rays", "max_samples_per_ray")
        _check(self, 1, math.inf, *counts, "occupancy_resolution", "occupancy_every", integer=True)
        _check(self, 0, math.inf, "cos_anneal_steps", integer=True)
        _check(self, 0, 1, "min_transmittance", ends="[)")
        _check(self, 0, 1, "reg_fraction", ends="(]")
        _check(self, 0, math.inf, "lambda_e", "lambda_n", "lambda_s", "lambda_k", "sharp_floor", "smooth_eps")
        _check(self, 0, math.inf, "lambda_mask", "lambda_carve", "lambda_paint")
        _check(self, 1, math.inf, "prior_points", "visibility_every", integer=True)
        _check(self, 0, math.inf, "fd_eps", "step_size", ends="()")


def _check_stage(config) -> None:
    """The checks of the fields both training stages have."""
    _check(config, 1, math.inf, "steps", "eval_every", "checkpoint_every", "error_tile", integer=True)
    _check(config, 0, math.inf, "warmup_steps", "eval_views", integer=True)
    _check(config, 0, MAX_SEED, "seed", integer=True)
    _check(config, 0, math.inf, "lr_encoding", "lr_network", ends="()")
    _check(config, 0, 1, "final_lr_factor", ends="(]")
    _check(config, 0, 1, "error_sampling")
    _check(config, 0, math.inf, "checkpoint_seconds")
    _check_bool(config, "random_background")


@dataclass
class Stage2Config:
    """Stage-2 narrow-band fine-tuning (Procedure 4 lines 8-13): color loss only."""

    steps: int = 1000
    rays: int = 16384
    # stage 1's rates, ramped up over warmup_steps (a fresh Adam state's first steps are as large as the rate:
    # at once they throw the trained field off, lego -0.35 dB). Lego, 3500-step stage 1 then 584 stage-2
    # steps: 28.14 dB narrow band; the earlier 4e-3 / 5e-4 without warm-up: 27.82 (27.90 after 1200 steps)
    lr_encoding: float = 3e-2
    lr_network: float = 1e-2
    warmup_steps: int = 100
    final_lr_factor: float = 0.1
    random_background: bool = False  # see PixelSampler; only for images with alpha
    error_sampling: float = 0.0  # share of the rays drawn where the running error is high (see PixelSampler)
    error_tile: int = 16  # pixels per side of the tiles whose error PixelSampler keeps
    lambda_paint: float = 0.1  # stage 1's paint term of the unseen prior (neural.visibility), kept on
    prior_points: int = 4096
    eval_every: int = 500
    eval_views: int = 2  # held-out views of the periodic evaluations (0: all); the final one uses all
    checkpoint_every: int = 250
    checkpoint_seconds: float = 120.0  # also checkpoint when this much time passed since the last one
    seed: int = 1

    def __post_init__(self):
        _check_stage(self)
        _check(self, 1, math.inf, "rays", "prior_points", integer=True)
        _check(self, 0, math.inf, "lambda_paint")


@dataclass
class ShellConfig:
    """Settings of Procedure 2. Paper values where the paper gives them (T, dt, zeta, lambda_curv).

    Bounds from the falloff: a node with ``|f0| >= zeta`` never moves (Eq. 5), so M+ stays inside
    ``f0 < zeta_dilate`` and M- outside ``f0 > -zeta_erode`` whatever the velocities; the front slows down
    as it nears these bounds.

    The paper leaves ``beta_d``, ``sigma_min``, ``beta_e`` and ``v_max`` open. On a unit-gradient SDF with
    kernel size ``s`` (``s_v = s / voxel``) the defaults give, within those bounds:

    - dilation (Eq. 6) out to where the voxel opacity falls to ``sigma_min``: ``voxel/2 + s ln(1/sigma_min)``
      for a sharp surface (``s_v << 1``: ~1 voxel) and ``s ln(1/(sigma_min s_v) - 1)`` for fuzzy content
      (opacity left outside the shell along the normal: ``sigma_min s_v``, 1% at ``s_v = 2``). ``beta_d``
      is large so that the front reaches that contour within ``T dt``; the speed is then capped at
      ``v_max`` (Eq. 6 has no cap; without one, ``beta_d alpha`` would break the explicit scheme);
    - erosion (Eq. 7) to the depth ``T dt min(v_max, beta_e / alpha_in)`` voxels, with
      ``alpha_in = 1 - exp(-1/s_v)`` the voxel opacity inside: 2 voxels for a sharp surface,
      ``2 s + 1 voxel`` for fuzzy content (transmittance left along the normal ``Phi(-2 - 1/s_v) < 12%``),
      plus up to ~half a voxel from the first-order upwinding across the jump of the speed at the surface;
    - ``v_max = 5`` voxels per unit time: half a voxel per Euler step of ``dt = 0.1``, the stability limit
      of the explicit upwind scheme, so Procedure 1 runs without sub-steps.

    ``lambda_curv_dilate = 0.01`` voxels^2 per unit time (paper) is a mild regulariser: over ``T dt = 5``
    it smooths features of about half a voxel.

    ``min_part_fraction`` (ours, not the paper's): M+ parts enclosing fewer grid nodes than this fraction of
    the largest part are dropped with the M- inside them. These are floaters that the training views only
    ever saw against the background (the lego field trained on white grows 47 of them, the largest 2% of
    the model's volume): they cost samples and would split the simulation cage. 0 keeps every part.
    """

    resolution: int = 256  # grid samples per axis over the unit cube
    steps: int = 50  # T
    dt: float = 0.1
    zeta_dilate: float = 0.1  # soft-falloff width of the dilation (Eq. 5), unit-space length
    lambda_curv_dilate: float = 0.01  # voxels^2 per unit time
    zeta_erode: float = 0.05
    lambda_curv_erode: float = 0.0
    beta_d: float = 100.0  # Eq. 6 coefficient, voxels per unit time per unit opacity
    sigma_min: float = 0.005  # Eq. 6 threshold on the voxel opacity alpha
    beta_e: float = 0.4  # Eq. 7 coefficient, voxels per unit time times opacity
    v_max: float = 5.0  # cap on both speeds, voxels per unit time
    min_part_fraction: float = 0.05  # drop M+ parts smaller than this fraction of the largest (nodes inside)
    chunk: int = 1 << 19  # band nodes per chunk of the level-set update

    def __post_init__(self):
        _check(self, 8, math.inf, "resolution", integer=True)
        _check(self, 0, math.inf, "steps", integer=True)
        _check(self, 1, math.inf, "chunk", integer=True)
        positive = ("dt", "zeta_dilate", "zeta_erode", "beta_d", "sigma_min", "beta_e", "v_max")
        _check(self, 0, math.inf, *positive, ends="()")
        _check(self, 0, math.inf, "lambda_curv_dilate", "lambda_curv_erode")
        _check(self, 0, 1, "min_part_fraction")


@dataclass(frozen=True)
class NarrowBandConfig:
    """Narrow-band sampling settings (Procedure 3), lengths in world units.

    The paper gives no numbers for ``delta_s`` and ``w_s``; the defaults suit a scene scaled to the unit
    cube ``[-1, 1]^3``: a band thinner than 0.03 (a solid surface, up to ~4 voxels of a 256^3 extraction)
    gets one sample, a fuzzy band 0.1 wide gets eight. Use :meth:`scaled` for scenes of another size.
    ``n_max = 16`` is the paper's cap (Fig. 6). The paper gives no ``dp_max``: 16 M+ hits (8 intervals) are
    needed on lego, whose studs and treads a ray crosses many times; with 8 hits its held-out narrow band
    lost 0.46 dB (28.18 against 28.64 dB at 2.70 samples per pixel), 32 gain nothing more.
    """

    delta_s: float = 0.01  # target spacing between samples
    w_s: float = 0.03  # intervals narrower than this get a single sample at their centre
    n_max: int = 16  # most samples per interval (N_max)
    max_peel: int = 16  # most M+ hits taken per ray (dp_max)

    def __post_init__(self):
        _check(self, 0, math.inf, "delta_s", ends="()")
        _check(self, 0, math.inf, "w_s")
        _check(self, 1, math.inf, "n_max", "max_peel", integer=True)

    def scaled(self, scale: float) -> NarrowBandConfig:
        """The same settings for a scene ``scale`` times larger (``delta_s`` and ``w_s`` times ``scale``)."""
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        return replace(self, delta_s=self.delta_s * scale, w_s=self.w_s * scale)


@dataclass
class PipelineConfig:
    """Everything ``shellsim train`` sets. Lengths of the stage settings are in the field's unit space."""

    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    stage1: Stage1Config = dataclasses.field(default_factory=Stage1Config)
    shell: ShellConfig = dataclasses.field(default_factory=ShellConfig)
    narrowband: NarrowBandConfig = dataclasses.field(default_factory=NarrowBandConfig)
    stage2: Stage2Config = dataclasses.field(default_factory=Stage2Config)
    downscale: int = 1
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    bound: float | None = None  # half-size of the object's box in world units; None: from the dataset
    space: str = "auto"  # one of SPACES

    def __post_init__(self):
        _check(self, 1, math.inf, "downscale", integer=True)
        _check_choice(self, "space", SPACES)
        rgb = self.background
        if not (isinstance(rgb, tuple | list) and len(rgb) == 3 and all(0 <= c <= 1 for c in rgb)):
            raise ConfigError(PipelineConfig, "background", "three numbers in [0, 1]", rgb)
        if self.bound is not None:
            _check(self, 0, math.inf, "bound", ends="()")


QUICK_STEPS = 2000  # stage-1 runs shorter than this are a quick try: smaller batches and grids


def scaled_defaults(stage1_steps: int) -> dict:
    """Settings that go with ``stage1_steps`` (``shellsim train`` applies them unless set explicitly).

    Stage 2 takes 1/6 of stage 1 (1000 for the default 6000). A quick try (fewer than ``QUICK_STEPS``)
    also trains on 16384 instead of 65536 samples per batch with a 64^3 instead of 128^3 occupancy grid,
    and extracts its shells on a 128^3 instead of 256^3 grid: each about 4-8x cheaper, so that 200 steps
    at a small downscale take minutes. The unseen prior is measured every third of the steps, at most every
    2000."""
    quick = stage1_steps < QUICK_STEPS
    return {
        "stage2_steps": max(1, math.ceil(stage1_steps / 6)),
        "shell_resolution": 128 if quick else ShellConfig.resolution,
        "target_samples": 16384 if quick else Stage1Config.target_samples,
        "occupancy_resolution": 64 if quick else Stage1Config.occupancy_resolution,
        "visibility_every": max(1, min(Stage1Config.visibility_every, stage1_steps // 3)),
    }
