"""Analytic wind on the cage (DESIGN step 6): a time-varying displacement of the rest cage's vertices.

No simulation: the object is treated as a cantilever anchored at its base and loaded by the wind.

- **Profile.** ``h`` is a vertex's height above the anchor along the bending axis ``a`` (``up``, or the
  anchor's axis). The lateral deflection follows Euler-Bernoulli beam theory under a uniform load,
  ``w''(h) = M(h) / EI(h)`` with ``M(h) = (L - h)^2 / 2`` and ``w(0) = w'(0) = 0`` (clamped base), so it
  grows monotonically with height, like ``(h^4 - 4 L h^3 + 6 L^2 h^2) / (3 L^4)`` for a uniform rod. Thin
  parts bend more: ``EI(h) ~ r(h)^k`` with ``r(h)`` the RMS radius of the cage's cross-section
  perpendicular to ``a`` at that height and ``k = WindField.thinness`` (``k = 4`` for a solid rod).
  ``w`` is normalised to 1 at the tip.
- **Amplitude.** The tip deflects by ``strength * L * m(x, t)`` along the horizontal wind direction
  ``w_hat``, where ``m = ramp(t) (1 + gust sin(2 pi f t) + turbulence n(x, t))``. ``n`` is a sum of three
  sinusoidal modes (wavelengths ``wavelength * L / k``, amplitudes ``~1/k``, ``max |n| <= 1``) travelling
  along ``w_hat`` at the speed ``wavelength * L * f`` (Taylor's frozen turbulence); a second set of
  modes makes the object flutter sideways (``ell_hat = a x w_hat``) with half that amplitude.
- **Length.** Bending a rod sideways by ``u(h)`` lowers it by ``int_0^h u'(s)^2 / 2 ds`` when its length is
  kept; the same drop is applied along ``-a``.
- **Anchor.** Vertices with ``h <= 0`` never move (``w(0) = 0`` exactly). ``anchor`` is a vertex selection
  of :mod:`~shellsim.physics.selection`, the grammar of ``simulate --pin``: ``"z<0.05"`` or ``"z<5%"``
  (everything below is fixed, the object stands on it), ``"z>0.9"`` (it hangs from it); ``<`` and ``<=``
  fix the same vertices, since those on the threshold have ``h = 0``. None anchors the lowest
  ``base_fraction`` of the cage along ``up``.

- **Limit.** The second-order drop leaves a tet the volume ratio ``1 - slope^2 / 2``, and turbulence
  compresses the cage along the wind: where a frame would squeeze a tet below
  :data:`~shellsim.tetcage.geometry.MIN_VOLUME_RATIO`, :func:`limited_wind_displacement` scales that frame's
  tip deflection down until none does: a gust too strong for the cage bends it as far
  as it can go. ``strength`` itself is at most 1 (:data:`RANGES`).

Frame 0 (``t = 0``) is the rest cage when ``ramp_seconds > 0``. Plain numpy; no torch; the wind job
(:mod:`shellsim.jobs.wind`) records the frames.
"""

from __future__ import annotations

import json
import math
import numbers
from dataclasses import asdict, dataclass

import numpy as np

from neural.errors import InputError
from shellsim.physics.selection import parse_selection
from shellsim.tetcage.geometry import MIN_VOLUME_RATIO, tet_volumes

_BINS = 64  # resolution of the beam profile along the bending axis
_MODES = 3  # turbulence modes


def _plain(v) -> str:
    """A vector or number as the user would type it: ``"0, 0, 1"``, ``"0.5"``."""
    try:
        return ", ".join(f"{float(c):g}" for c in np.ravel(np.asarray(v, dtype=np.float64)))
    except (TypeError, ValueError):
        return repr(v)


def _unit(name: str, v) -> tuple[float, float, float]:
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(1, np.nan)
    norm = float(np.linalg.norm(arr)) if arr.shape == (3,) else math.nan
    if not (math.isfinite(norm) and norm > 0):
        raise InputError(f"wind {name}: expected a non-zero finite vector x, y, z, got {_plain(v)}")
    return tuple(float(c) for c in arr / norm)


# Valid ranges [low, high] of the numeric settings. strength <= 1: a mean tip deflection of the object's
# height is already where the bending folds the cage (a uniform rod's tip slope is 4/3 strength and its
# tets keep the volume ratio 1 - slope^2 / 2, below MIN_VOLUME_RATIO from strength 0.95 on); gust <= 1:
# the gusts modulate the wind's speed and do not reverse it; turbulence <= 1: |n| <= 1, the same bound.
RANGES: dict[str, tuple[float, float]] = {
    "strength": (0, 1),
    "gust": (0, 1),
    "frequency": (0, 10),  # Hz; also at most max_frequency(fps)
    "turbulence": (0, 1),
    "wavelength": (0.05, 100),  # / L
    "base_fraction": (0, 0.95),
    "thinness": (0, 8),
    "ramp_seconds": (0, 3600),
    "seed": (0, 2**32 - 1),
}


def max_frequency(fps: float) -> float:
    """Largest gust frequency [Hz] that frames at ``fps`` can show: the fastest turbulence mode (``_MODES``
    times the frequency) stays below the Nyquist rate ``fps / 2``."""
    return fps / (2 * _MODES)


@dataclass
class WindField:
    """Wind parameters; lengths are relative to the object's height ``L`` above the anchor."""

    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)  # normalised; its component along a is dropped
    strength: float = 0.05  # mean tip deflection / L
    gust: float = 0.3  # relative amplitude of the gusts
    frequency: float = 0.5  # Hz, gusts and the longest turbulence mode
    turbulence: float = 0.2  # relative amplitude of the travelling modes
    wavelength: float = 1.0  # of the longest turbulence mode, / L
    anchor: str | None = None  # "AXIS OP VALUE[%]" (physics.selection); None: lowest base_fraction along up
    base_fraction: float = 0.05
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    thinness: float = 2.0  # exponent k of EI(h) ~ r(h)^k; 0 ignores the cross-section
    ramp_seconds: float = 0.5  # the wind rises smoothly from 0 over this time
    seed: int = 0  # phases and directions of the turbulence modes

    def __post_init__(self):
        self.direction = _unit("direction", self.direction)
        self.up = _unit("up", self.up)
        for name, (low, high) in RANGES.items():
            value = getattr(self, name)
            ok = isinstance(value, numbers.Integral if name == "seed" else numbers.Real)
            if not (ok and low <= value <= high):  # NaN fails too
                raise InputError(f"wind {name}: expected {low} <= {name} <= {high}, got {_plain(value)}")
        if self.anchor is not None:
            parse_selection(self.anchor, "anchor")
        axis = self.bending_axis()
        if abs(float(np.dot(self.direction, axis))) > 1 - 1e-6:
            raise InputError(
                f"wind direction {_plain(self.direction)} is along the object's bending axis "
                f"{_plain(axis)}: nothing bends; give it a component across that axis"
            )

    def bending_axis(self) -> np.ndarray:
        """(3,) unit vector from the anchored base towards the free end."""
        if self.anchor is None:
            return np.asarray(self.up)
        anchor = parse_selection(self.anchor, "anchor")
        return anchor.sign * np.eye(3)[anchor.axis]


def heights(rest_vertices: np.ndarray, settings: WindField) -> np.ndarray:
    """(V,) height of each rest vertex above the anchor along the bending axis (<= 0: anchored)."""
    rest = _as_vertices(rest_vertices)
    if settings.anchor is None:
        along = rest @ np.asarray(settings.up)
        if not along.max() > along.min():
            raise InputError(f"the cage has no extent along the up axis {settings.up}: nothing to bend")
        return along - (along.min() + settings.base_fraction * (along.max() - along.min()))
    anchor = parse_selection(settings.anchor, "anchor")
    h = anchor.sign * (rest[:, anchor.axis] - anchor.threshold(rest))
    if h.max() <= 0 or h.min() > 0:
        raise anchor.refusal("anchor", rest, "every" if h.max() <= 0 else "no")
    return h


def beam_profile(rest_vertices: np.ndarray, settings: WindField):
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


def wind_displacement(rest_vertices, t: float, settings: WindField) -> np.ndarray:
    """Displacement of every cage vertex at time ``t`` (seconds).

    rest_vertices : (V, 3) float
    returns : (V, 3) float64; exactly zero at anchored vertices, and everywhere when ``strength == 0``
    """
    bend, sink = _bend_and_sink(_as_vertices(rest_vertices), t, settings)
    return bend - sink


def _bend_and_sink(rest: np.ndarray, t: float, settings: WindField) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of the displacement at ``t``, (V, 3) each: the lateral bending, linear in the tip
    deflection ``A``, and the inextensibility drop along ``-a``, quadratic in it. The displacement with
    ``A`` scaled by ``s`` is ``s bend - s^2 sink``."""
    if settings.strength == 0:
        return np.zeros_like(rest), np.zeros_like(rest)
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
    bent = (lateral * bend)[:, None] * wind + (lateral * flutter)[:, None] * side
    sunk = sink[:, None] * axis
    bent[h <= 0] = 0.0
    sunk[h <= 0] = 0.0
    return bent, sunk


def limited_wind_displacement(
    rest_vertices, tets, t: float, settings: WindField, floor: float = MIN_VOLUME_RATIO
) -> tuple[np.ndarray, float, float]:
    """:func:`wind_displacement` with the tip deflection scaled down where it would fold the cage.

    The displacement ``s bend - s^2 sink`` (:func:`_bend_and_sink`) keeps the shape of the bent rod and
    its length; ``s`` is 1 when every tet keeps a volume ratio ``>= floor``, else the largest ``s`` in
    [0, 1) found by bisection for which every tet does (``s = 0`` is the rest cage, ratio 1). In a gust
    too strong for the cage the object bends as far as it can and stays there until the gust passes.

    rest_vertices : (V, 3) float; tets : (T, 4) int, positively oriented
    returns : displacement (V, 3) float64, the scale ``s`` and the smallest volume ratio of the frame
    """
    rest = _as_vertices(rest_vertices)
    tets = np.asarray(tets, dtype=np.int64)
    rest_volumes = tet_volumes(rest, tets)
    if not (rest_volumes > 0).all():
        bad = int((rest_volumes <= 0).sum())
        raise ValueError(f"tets: {bad} of {len(tets)} are not positively oriented at rest")
    bend, sink = _bend_and_sink(rest, t, settings)

    def worst(s: float) -> float:
        return float((tet_volumes(rest + s * bend - s * s * sink, tets) / rest_volumes).min())

    scale, ratio = 1.0, worst(1.0)
    if not ratio >= floor:
        low, high = 0.0, 1.0  # worst(low) >= floor > worst(high)
        for _ in range(24):
            mid = 0.5 * (low + high)
            low, high = (mid, high) if worst(mid) >= floor else (low, mid)
        scale, ratio = low, worst(low) if low > 0 else 1.0
    return scale * bend - scale * scale * sink, scale, ratio


def _turbulence(rest: np.ndarray, t: float, wind: np.ndarray, length: float, settings: WindField):
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


def wind_record(field: WindField, fps: float) -> dict:
    """The settings a wind motion records: the model, ``fps`` and the fields of ``field``."""
    fields = json.loads(json.dumps(asdict(field)))
    return {"model": "analytic cantilever wind", "fps": float(fps), **fields}


#: Names of the wind settings whose option is not ``--key-with-dashes``.
SETTING_NAMES = {"up": "the asset's up axis", "base_fraction": "base fraction"}
