"""Material presets for the elastic simulation: Young's modulus, Poisson ratio and density in SI units.

Values are typical room-temperature figures from engineering handbooks (Engineering ToolBox tables,
Callister & Rethwisch *Materials Science and Engineering*, Gibson & Ashby *Cellular Solids* for foam,
Czerner et al. 2015 for gelatin gels); the ranges are wide and the preset picks a representative value:

=======  =================  ================  ============  ==========================  ===========
name     Young's modulus E  Poisson ratio nu  density rho   typical range of E          holds up to
=======  =================  ================  ============  ==========================  ===========
jelly    10 kPa             0.45              1050 kg/m^3   1-30 kPa (gelatin gel)      10 cm
foam     100 kPa            0.25              40 kg/m^3     10 kPa-1 MPa (flexible PU)  25 m
rubber   2 MPa              0.45              1100 kg/m^3   1-10 MPa (soft rubber)      18 m
plastic  2.3 GPa            0.35              1050 kg/m^3   1.5-3 GPa (ABS)             22 km
wood     10 GPa             0.35              600 kg/m^3    8-14 GPa (along grain)      170 km
metal    200 GPa            0.29              7850 kg/m^3   190-210 GPa (steel)         260 km
=======  =================  ================  ============  ==========================  ===========

"Holds up to": the height ``H = 0.1 E / (rho g)`` of a block standing on the ground that sags 5% of its height
under its own weight (:func:`shellsim.physics.sag.column_sag`: ``rho g H^2 / (2 E)``); a shape that overhangs
(a head, ears) sags about 3.5 times as much, so it holds to 5% only up to about a third of that height
(docs/simulation.md, "materials that hold their shape").

Nearly incompressible materials (rubber, gels: nu ~ 0.49-0.5) use nu = 0.45 here: it limits the volumetric
locking of linear tetrahedra and keeps the Newton systems well conditioned. Wood is treated as isotropic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from neural.errors import InputError


@dataclass(frozen=True)
class Material:
    """An isotropic elastic material in SI units.

    youngs : Young's modulus E [Pa]; poisson : Poisson ratio nu in (-1, 0.5); density : rho [kg/m^3].
    """

    name: str
    youngs: float
    poisson: float
    density: float

    def __post_init__(self):
        if not (math.isfinite(self.youngs) and self.youngs > 0):
            raise InputError(f"material {self.name!r}: Young's modulus must be > 0 Pa, got {self.youngs}")
        if not (math.isfinite(self.poisson) and -1.0 < self.poisson < 0.5):
            raise InputError(
                f"material {self.name!r}: Poisson ratio must lie in (-1, 0.5), got {self.poisson}"
            )
        if not (math.isfinite(self.density) and self.density > 0):
            raise InputError(f"material {self.name!r}: density must be > 0 kg/m^3, got {self.density}")

    @property
    def mu(self) -> float:
        """Lamé's second parameter (shear modulus) mu = E / (2 (1 + nu)) [Pa]."""
        return self.youngs / (2.0 * (1.0 + self.poisson))

    @property
    def lam(self) -> float:
        """Lamé's first parameter lambda = E nu / ((1 + nu)(1 - 2 nu)) [Pa]."""
        return self.youngs * self.poisson / ((1.0 + self.poisson) * (1.0 - 2.0 * self.poisson))

    def as_dict(self) -> dict:
        return {"name": self.name, "youngs": self.youngs, "poisson": self.poisson, "density": self.density}


# Valid ranges of user overrides, (low, high, ends) with ends "[]", "()", ...: Young's modulus from below the
# softest gels (1 kPa) to above diamond (about 1.1 TPa); densities from aerogel to above osmium (22.6 t/m^3).
RANGES: dict[str, tuple[float, float, str]] = {
    "youngs": (1.0e2, 2.0e12, "[]"),
    "poisson": (-1.0, 0.5, "()"),
    "density": (1.0, 1.0e5, "[]"),
}
_NAMES = {
    "youngs": ("Young's modulus", " Pa"),
    "poisson": ("Poisson ratio", ""),
    "density": ("density", " kg/m^3"),
}

PRESETS: dict[str, Material] = {
    m.name: m
    for m in (
        Material("jelly", 1.0e4, 0.45, 1050.0),
        Material("foam", 1.0e5, 0.25, 40.0),
        Material("rubber", 2.0e6, 0.45, 1100.0),
        Material("plastic", 2.3e9, 0.35, 1050.0),
        Material("wood", 1.0e10, 0.35, 600.0),
        Material("metal", 2.0e11, 0.29, 7850.0),
    )
}


def get_material(
    name: str, youngs: float | None = None, poisson: float | None = None, density: float | None = None
) -> Material:
    """The preset ``name`` with any of ``youngs`` [Pa], ``poisson``, ``density`` [kg/m^3] overriding it.

    Unknown names and values outside :data:`RANGES` raise :class:`InputError`.
    """
    key = str(name).strip().lower()
    if key not in PRESETS:
        raise InputError(f"unknown material {name!r}; known materials: {', '.join(PRESETS)}")
    overrides = {
        k: float(v)
        for k, v in (("youngs", youngs), ("poisson", poisson), ("density", density))
        if v is not None
    }
    for k, v in overrides.items():
        low, high, ends = RANGES[k]
        if not ((v > low if ends[0] == "(" else v >= low) and (v < high if ends[1] == ")" else v <= high)):
            what, unit = _NAMES[k]
            span = f"{ends[0]}{low:g}, {high:g}{ends[1]}{unit}"
            raise InputError(f"{what} {v:g}{unit}: expected a value in {span}")
    return replace(PRESETS[key], **overrides)
