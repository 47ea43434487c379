"""Build (or load) the tetrahedral cage of an asset (paper Sec. 5) and describe it.

Where the cage lives and when it is rebuilt: :func:`shellsim.tetcage.store.load_or_build_cage`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from shellsim.errors import SettingError
from shellsim.settings import check_required, option
from shellsim.tetcage.build import CageConfig


@dataclass(frozen=True)
class CageSettings:
    """What ``shellsim cage`` takes. Neither ``tets`` nor ``margin`` set: the asset's own cage whatever its
    settings; one set: the other takes :class:`~shellsim.tetcage.build.CageConfig`'s default."""

    asset: str = option(help="asset directory, or the name of a shipped asset", required=True)
    tets: int | None = option(
        help="target number of tets", shown_default=f"the asset's cage's, else {CageConfig.target_tets}"
    )
    margin: float | None = option(
        help="dilation of M+, relative to its bounding-box diagonal",
        shown_default=f"the asset's cage's, else {CageConfig.margin:g}",
    )
    rebuild: bool = option(False, help="rebuild even if a matching cage.npz exists")

    def __post_init__(self):
        check_required(self)
        for name, key in (("tets", "target_tets"), ("margin", "margin")):
            if getattr(self, name) is not None:
                try:
                    CageConfig(**{key: getattr(self, name)})
                except ValueError as err:
                    raise SettingError(name, str(err)) from None

    def cage_config(self) -> CageConfig | None:
        """The cage's settings; None: the asset's own cage, whatever they are."""
        given = {k: v for k, v in (("target_tets", self.tets), ("margin", self.margin)) if v is not None}
        return CageConfig(**given) if given else None


@dataclass(frozen=True)
class CageResult:
    """The cage :func:`cage` loaded or built (facts of :func:`~shellsim.tetcage.store.cage_summary`).

    name : the asset's name; path : the cage file; config : its :class:`~shellsim.tetcage.build.CageConfig`
    seconds : wall time of loading or building it
    vertices, tets : V and T, the cage's vertex and tet counts; volume : its volume (asset units cubed)
    min_quality, median_quality : tet quality (1 = regular)
    outer_vertices, inner_vertices : vertices of M+ and M- embedded in it; outside : how many of them lie
        outside the cage (embedded with extrapolated coordinates), at most ``max_outside_distance`` from it
    """

    name: str
    path: Path
    config: CageConfig
    seconds: float
    vertices: int
    tets: int
    volume: float
    min_quality: float
    median_quality: float
    outer_vertices: int
    inner_vertices: int
    outside: int
    max_outside_distance: float


def cage(settings: CageSettings) -> CageResult:
    """Load or build the cage of ``settings.asset`` and describe it."""
    from neural.asset import load_asset
    from shellsim.memory import check_memory, tetwild_bytes
    from shellsim.tetcage.store import cage_summary, load_or_build_cage

    if settings.tets:
        what = f"a cage of {settings.tets:,} tets"
        check_memory("tets", tetwild_bytes(settings.tets), what, "to build")
    asset = load_asset(settings.asset)
    start = time.perf_counter()
    built = load_or_build_cage(asset, settings.cage_config(), rebuild=settings.rebuild)
    seconds = time.perf_counter() - start
    return CageResult(
        name=asset.name, path=Path(built.path), config=built.config, seconds=seconds, **cage_summary(built)
    )
