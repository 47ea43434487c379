"""How far a body sinks under its own weight when it stands on the ground, said before simulating.

**The standing column.** Take the body as a column along ``up`` whose horizontal slice at height ``z`` above
its base has the area ``A(z)`` and carries the weight of everything above it, ``W(z) = rho g V(z)``
(``V(z)`` the volume above ``z``), as a uniform compressive stress ``W / A``. Each slice shortens by the
uniaxial strain ``eps(z) = rho g V(z) / (E A(z))`` (laterally free: no Poisson confinement), and the top
comes down by their sum

    delta = (rho g / E) int_base^top V(z) / A(z) dz.

A prism of height ``H`` gives ``V / A = H - z`` and ``delta = rho g H^2 / (2 E)``: the strain at its base,
``rho g H / E``, times half its height. A cone standing on its base (``V / A = (H - z) / 3``) gives a third
of that. The estimate counts compression only: parts that overhang (a head, ears) also bend, and large
strains can buckle a shape into a collapse, so a body's simulated sag is larger (docs/simulation.md,
"materials that hold their shape", gives the measured factors). It scales as ``rho / E``, so the Young's
modulus that holds a body to a fraction ``f`` of its height is ``E delta / (f H)``.

``A`` and ``V`` come from the cage: every tet's volume spread over its height by :data:`POINTS_PER_TET`
fixed points spread evenly over it (low-discrepancy: a scrambled Sobol sequence mapped to the simplex),
binned into :data:`SLICES` slices.
"""

from __future__ import annotations

import math

import numpy as np

#: Slices of a body's height, and points per tet that spread each tet's volume over the slices.
SLICES = 64
POINTS_PER_TET = 64


def _spread_points() -> np.ndarray:
    """(P, 4) fixed barycentric coordinates spread evenly over a tet: the gaps between the sorted coordinates
    of P points of a seeded scrambled Sobol sequence in the unit cube (uniform on the simplex)."""
    from scipy.stats import qmc

    cube = np.sort(qmc.Sobol(3, scramble=True, seed=0).random(POINTS_PER_TET), axis=1)
    return np.diff(
        np.concatenate([np.zeros((POINTS_PER_TET, 1)), cube, np.ones((POINTS_PER_TET, 1))], 1), axis=1
    )


def column_sag(vertices, tets, density: float, youngs: float, gravity: float, up=(0.0, 0.0, 1.0), base=None):
    """The standing column's sag ``delta`` [m] (module docstring) of the tet mesh ``vertices`` (V, 3) [m],
    ``tets`` (T, 4), of ``density`` [kg/m^3] and Young's modulus ``youngs`` [Pa] under ``gravity``
    [m/s^2] along ``-up``, standing at the height ``base`` [m along up] (None: its lowest vertex; the part
    below it, a cage's margin under the ground, carries nothing)."""
    if not (youngs > 0 and density > 0 and gravity >= 0):
        raise ValueError(f"youngs, density > 0 and gravity >= 0 expected, got {youngs}, {density}, {gravity}")
    x = np.asarray(vertices, np.float64)
    tets = np.asarray(tets, np.int64)
    corners = x[tets]  # (T, 4, 3)
    e = corners[:, 1:] - corners[:, :1]
    volumes = np.abs(np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2]))) / 6.0
    unit = np.asarray(up, np.float64) / np.linalg.norm(up)
    heights = np.einsum("pk,tk->tp", _spread_points(), corners @ unit).ravel()  # (T P,)
    low = heights.min() if base is None else max(float(base), heights.min())
    top = heights.max()
    if gravity == 0 or top <= low:
        return 0.0
    weights = np.repeat(volumes / POINTS_PER_TET, POINTS_PER_TET)
    slab, _ = np.histogram(heights, SLICES, (low, top), weights=weights)  # (S,) volume of each slice
    dz = (top - low) / SLICES
    above = np.cumsum(slab[::-1])[::-1] - 0.5 * slab  # volume above each slice's middle
    area = slab / dz
    carried = np.divide(above, area, out=np.zeros_like(above), where=area > 0)
    return density * gravity / youngs * float(carried.sum() * dz)


def holding_youngs(youngs: float, sag: float, height: float, fraction: float = 0.05) -> float:
    """The Young's modulus [Pa] that holds a body of ``youngs`` [Pa] and estimated ``sag`` [m] to
    ``fraction`` of its ``height`` [m] (the sag scales as ``1 / E``), rounded up to 2 significant figures."""
    wanted = youngs * sag / (fraction * height)
    scale = 10.0 ** (math.floor(math.log10(wanted)) - 1)
    return math.ceil(wanted / scale - 1e-9) * scale
