"""Analytic wind on the cage (DESIGN step 6): a time-varying displacement of the rest cage's vertices.

No simulation: the object is treated as a cantilever anchored at its base and loaded by the wind.

- **Profile.** ``h`` is a vertex's height above the anchor along the bending axis ``a`` (``up``, or the
  anchor's axis). The lateral deflection follows Euler-Bernoulli beam theory under a uniform load,
  ``w''(h) = M(h) / EI(h)`` with ``M(h) = (L - h)^2 / 2`` and ``w(0) = w'(0) = 0`` (clamped base), so it
  grows monotonically with height, like ``(h^4 - 4 L h^3 + 6 L^2 h^2) / (3 L^4)`` for a uniform rod. Thin
  parts bend more: ``EI(h) ~ r(h)^k`` with ``r(h)`` the RMS radius of the cage's cross-section
  perpendicular to ``a`` at that height and ``k = WindSettings.thinness`` (``k = 4`` for a solid rod).
  ``w`` is normalised to 1 at the tip.
- **Amplitude.** The tip deflects by ``strength * L * m(x, t)`` along the horizontal wind direction
  ``w_hat``, where ``m = ramp(t) (1 + gust sin(2 pi f t) + turbulence n(x, t))``. ``n`` is a sum of three
  sinusoidal modes (wavelengths ``wavelength * L / k``, amplitudes ``~1/k``, ``max |n| <= 1``) travelling
  along ``w_hat`` at the speed ``wavelength * L * f`` (Taylor's frozen turbulence); a second set of
  modes makes the object flutter sideways (``ell_hat = a x w_hat``) with half that amplitude.
- **Length.** Bending a rod sideways by ``u(h)`` lowers it by ``int_0^h u'(s)^2 / 2 ds`` when its length is
  kept; the same drop is applied along ``-a``.
- **Anchor.** Vertices with ``h <= 0`` never move (``w(0) = 0`` exactly). ``anchor`` is a vertex selection
  of :mod:`shellsim.selection`, the grammar of ``simulate --pin``: ``"z<0.05"`` or ``"z<5%"`` (everything
  below is fixed, the object stands on it), ``"z>0.9"`` (it hangs from it); ``<`` and ``<=`` fix the same
  vertices, since those on the threshold have ``h = 0``. None anchors the lowest ``base_fraction`` of the
  cage along ``up``.

Frame 0 of :func:`animate_wind` is the rest cage when ``ramp_seconds > 0``. Plain numpy; no torch.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from neural.errors import InputError

from .selection import Selection, parse_selection

log = logging.getLogger(__name__)

_BINS = 64  # resolution of the beam profile along the bending axis
_MODES = 3  # turbulence modes


def parse_anchor(spec) -> Selection:
    """``"z<0.05"``, ``"z<5%"`` -> a :class:`Selection`; anything else is an :class:`InputError`."""
    try:
        return parse_selection(spec)
    except InputError as err:
        raise InputError(f"anchor {err}") from None


def _unit(name: str, v) -> tuple[float, float, float]:
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(1, np.nan)
    norm = float(np.linalg.norm(arr)) if arr.shape == (3,) else math.nan
    if not (math.isfinite(norm) and norm > 0):
        raise InputError(f"wind {name}: expected a non-zero finite vector x, y, z, got {v!r}")
    return tuple(float(c) for c in arr / norm)


@dataclass
class WindSettings:
    """Wind parameters; lengths are relative to the object's height ``L`` above the anchor."""

    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)  # normalised; its component along a is dropped
    strength: float = 0.05  # mean tip deflection / L
    gust: float = 0.3  # relative amplitude of the gusts
    frequency: float = 0.5  # Hz, gusts and the longest turbulence mode
    turbulence: float = 0.2  # relative amplitude of the travelling modes
    wavelength: float = 1.0  # of the longest turbulence mode, / L
    anchor: str | None = None  # "AXIS OP VALUE[%]" (shellsim.selection); None: lowest base_fraction along up
    base_fraction: float = 0.05
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    thinness: float = 2.0  # exponent k of EI(h) ~ r(h)^k; 0 ignores the cross-section
    ramp_seconds: float = 0.5  # the wind rises smoothly from 0 over this time
    seed: int = 0  # phases and directions of the turbulence modes

    def __post_init__(self):
        self.direction = _unit("direction", self.direction)
        self.up = _unit("up", self.up)
        checks = {
            "strength": self.strength >= 0,
            "gust": self.gust >= 0,
            "frequency": self.frequency >= 0,
            "turbulence": self.turbulence >= 0,
            "wavelength": self.wavelength > 0,
            "base_fraction": 0 <= self.base_fraction < 1,
            "thinness": self.thinness >= 0,
            "ramp_seconds": self.ramp_seconds >= 0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not (ok and math.isfinite(value)):
                raise InputError(f"wind {name}: invalid value {value!r}")
        if self.anchor is not None:
            parse_anchor(self.anchor)
        axis = self.bending_axis()
        if abs(float(np.dot(self.direction, axis))) > 1 - 1e-6:
            raise InputError(
                f"wind direction {self.direction} is along the object's axis {tuple(axis)}: nothing bends"
            )

    def bending_axis(self) -> np.ndarray:
        """(3,) unit vector from the anchored base towards the free end."""
        if self.anchor is None:
            return np.asarray(self.up)
        anchor = parse_anchor(self.anchor)
        return anchor.sign * np.eye(3)[anchor.axis]


def heights(rest_vertices: np.ndarray, settings: WindSettings) -> np.ndarray:
    """(V,) height of each rest vertex above the anchor along the bending axis (<= 0: anchored)."""
    rest = _as_vertices(rest_vertices)
    if settings.anchor is None:
        along = rest @ np.asarray(settings.up)
        if not along.max() > along.min():
            raise InputError(f"the cage has no extent along the up axis {settings.up}: nothing to bend")
        return along - (along.min() + settings.base_fraction * (along.max() - along.min()))
    anchor = parse_anchor(settings.anchor)
    h = anchor.sign * (rest[:, anchor.axis] - anchor.threshold(rest))
    if h.max() <= 0 or h.min() > 0:
        axis = "xyz"[anchor.axis]
        what = "every" if h.max() <= 0 else "no"
        raise InputError(
            f"anchor {settings.anchor!r} selects {what} cage vertex ({axis} spans "
            f"{rest[:, anchor.axis].min():.4g} .. {rest[:, anchor.axis].max():.4g})"
        )
    return h


def beam_profile(rest_vertices: np.ndarray, settings: WindSettings):
    """The normalised cantilever profile on a grid of heights.

    returns : grid (B+1,) heights 0..L; w (B+1,) deflection with w[0] = 0, w[-1] = 1; drop (B+1,)
        ``int_0^h w'^2 / 2`` (a tip deflection ``A`` lowers height ``h`` by ``A^2 drop(h)``), L (float)
    """
    rest = _as_vertices(rest_vertices)
    h = heights(rest, settings)
    length = float(h.max())
    grid = np.linspace(0.0, length, _BINS + 1)
    stiffness = np.ones_like(grid)
    if settings.thinness > 0:
        axis = settings.bending_axis()
        free = h > 0
        perp = rest[free] - np.outer(rest[free] @ axis, axis)
        bins = np.minimum((h[free] / length * _BINS).astype(np.int64), _BINS - 1)
        counts = np.bincount(bins, minlength=_BINS)
        centroid = np.stack([np.bincount(bins, perp[:, c], _BINS) for c in range(3)], 1)
        centroid /= np.maximum(counts, 1)[:, None]
        radius2 = np.bincount(bins, ((perp - centroid[bins]) ** 2).sum(1), _BINS) / np.maximum(counts, 1)
        full = counts > 0
        centres = (np.arange(_BINS) + 0.5) * length / _BINS
        radius = np.sqrt(np.interp(grid, centres[full], radius2[full]))
        radius = np.maximum(radius, 0.05 * radius.max()) if radius.max() > 0 else np.ones_like(grid)
        stiffness = (radius / radius.max()) ** settings.thinness
    curvature = 0.5 * (length - grid) ** 2 / stiffness
    slope = _cumtrapz(curvature, grid)
    w = _cumtrapz(slope, grid)
    slope, w = slope / w[-1], w / w[-1]
    return grid, w, _cumtrapz(0.5 * slope**2, grid), length


def _cumtrapz(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(x))])


def _as_vertices(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"rest_vertices: expected shape (V, 3) with V >= 1, got {v.shape}")
    return v


def wind_displacement(rest_vertices, t: float, settings: WindSettings) -> np.ndarray:
    """Displacement of every cage vertex at time ``t`` (seconds).

    rest_vertices : (V, 3) float
    returns : (V, 3) float64; exactly zero at anchored vertices, and everywhere when ``strength == 0``
    """
    rest = _as_vertices(rest_vertices)
    if settings.strength == 0:
        return np.zeros_like(rest)
    axis = settings.bending_axis()
    wind = np.asarray(settings.direction) - np.dot(settings.direction, axis) * axis
    wind /= np.linalg.norm(wind)
    side = np.cross(axis, wind)
    grid, w, drop, length = beam_profile(rest, settings)
    h = np.maximum(heights(rest, settings), 0.0)

    tau = 1.0 if settings.ramp_seconds == 0 else min(max(t / settings.ramp_seconds, 0.0), 1.0)
    ramp = tau * tau * (3.0 - 2.0 * tau)
    noise = _turbulence(rest, t, wind, length, settings)
    bend = ramp * (
        1.0 + settings.gust * math.sin(2 * math.pi * settings.frequency * t) + settings.turbulence * noise[0]
    )
    flutter = ramp * 0.5 * settings.turbulence * noise[1]

    tip = settings.strength * length
    lateral = tip * np.interp(h, grid, w)
    sink = tip**2 * (bend**2 + flutter**2) * np.interp(h, grid, drop)
    out = (lateral * bend)[:, None] * wind + (lateral * flutter)[:, None] * side - sink[:, None] * axis
    out[h <= 0] = 0.0
    return out


def _turbulence(rest: np.ndarray, t: float, wind: np.ndarray, length: float, settings: WindSettings):
    """(2, V) frozen turbulence in [-1, 1]: modes k = 1.._MODES of wavelength ``wavelength * L / k`` and
    amplitude ~1/k travelling along ``wind`` at ``wavelength * L * frequency``; row 0 drives the bending,
    row 1 the sideways flutter. Phases and a lean of each mode's fronts (up to 27 degrees) come from
    ``seed``."""
    rng = np.random.default_rng(settings.seed)
    phases = rng.uniform(0, 2 * math.pi, (2, _MODES))
    across = np.cross(wind, rng.normal(size=(2, _MODES, 3)))
    lean = rng.uniform(-0.5, 0.5, (2, _MODES, 1)) * across / np.linalg.norm(across, axis=-1, keepdims=True)
    k = np.arange(1, _MODES + 1)
    wavelength = settings.wavelength * length
    wavenumber = 2 * math.pi * k / wavelength  # (_MODES,)
    along = rest @ wind - wavelength * settings.frequency * t  # (V,)
    phase = wavenumber * (along[None, :, None] + np.einsum("vc,smc->svm", rest, lean)) + phases[:, None, :]
    return (np.sin(phase) / k).sum(-1) / (1.0 / k).sum()


def wind_meta(settings: WindSettings, fps: float) -> dict:
    """The motion file's ``meta`` for a wind animation: what made it and with which parameters."""
    return {
        "made_by": "shellsim.wind",
        "model": "analytic cantilever wind",
        "fps": float(fps),
        "settings": json.loads(json.dumps(asdict(settings))),
    }


def _volumes6(v: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) six times the signed tet volumes."""
    e = v[tets[:, 1:]] - v[tets[:, :1]]
    return np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2]))


def animate_wind(
    rest_vertices, tets, settings: WindSettings, frames: int, fps: float, writer, progress: bool = True
) -> None:
    """Append wind frames ``writer.n_frames .. frames - 1`` (times ``i / fps``) to a
    :class:`shellsim.motion.MotionWriter` made with :func:`wind_meta` (fresh or resumed).

    rest_vertices : (V, 3) float; tets : (T, 4) int, positively oriented. Records in ``meta["stats"]`` the
    smallest ratio of deformed to rest tet volume (<= 0: some tet inverted; lower ``strength``) and the
    wall time. Resuming a file made with other settings or another cage is an :class:`InputError`.
    """
    from tqdm import tqdm

    rest = _as_vertices(rest_vertices)
    tets = np.asarray(tets, dtype=np.int64)
    if not (isinstance(frames, int) and frames >= 1) or not (fps > 0 and math.isfinite(fps)):
        raise ValueError(f"frames >= 1 and fps > 0 expected, got frames={frames!r} fps={fps!r}")
    meta = writer.motion.meta
    wanted = wind_meta(settings, fps)
    if writer.n_frames and (meta.get("settings") != wanted["settings"] or meta.get("fps") != wanted["fps"]):
        raise InputError(
            f"{writer.path}: was made with other wind settings or fps ({meta.get('settings')}, "
            f"fps {meta.get('fps')}); drop --resume to start over"
        )
    same_cage = writer.motion.rest_vertices.shape == rest.shape and np.array_equal(writer.motion.tets, tets)
    if not (same_cage and np.allclose(writer.motion.rest_vertices, rest)):
        raise InputError(f"{writer.path}: its rest cage is not this asset's cage")
    meta.update(wanted)
    stats = meta.setdefault("stats", {})
    start, wall = time.perf_counter(), float(stats.get("wall_seconds", 0.0))
    rest_volumes = _volumes6(rest, tets)
    for i in tqdm(range(writer.n_frames, frames), desc="wind", unit="frame", disable=not progress):
        positions = rest + wind_displacement(rest, i / fps, settings)
        ratio = float((_volumes6(positions, tets) / rest_volumes).min())
        if ratio <= 0 and stats.get("min_volume_ratio", 1.0) > 0:
            log.warning("frame %d inverts cage tets (volume ratio %.3g): lower the wind strength", i, ratio)
        stats["min_volume_ratio"] = min(stats.get("min_volume_ratio", 1.0), ratio)
        stats["wall_seconds"] = wall + time.perf_counter() - start
        writer.append(positions, i / fps)
