"""Build (or load) the tetrahedral cage of an asset (paper Sec. 5) and describe it.

Where the cage lives and when it is rebuilt: :func:`shellsim.cage.store.load_or_build_cage`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from shellsim.cage.build import CageConfig
from shellsim.errors import SettingError
from shellsim.settings import option


@dataclass(frozen=True)
class CageSettings:
    """What ``shellsim cage`` takes. Neither ``tets`` nor ``margin`` set: the asset's own cage whatever its
    settings; one set: the other takes :class:`~shellsim.cage.build.CageConfig`'s default."""

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


def cage(settings: CageSettings) -> dict:
    """Load or build the cage of ``settings.asset``; returns :func:`~shellsim.cage.store.cage_summary` with the
    asset's ``name``, the cage's ``path`` and ``config`` and ``seconds`` (the wall time)."""
    from neural.asset import load_asset
    from shellsim.cage.store import cage_summary, load_or_build_cage

    asset = load_asset(settings.asset)
    start = time.perf_counter()
    built = load_or_build_cage(asset, settings.cage_config(), rebuild=settings.rebuild)
    seconds = time.perf_counter() - start
    return {
        **cage_summary(built),
        "name": asset.name,
        "path": built.path,
        "config": built.config,
        "seconds": seconds,
    }
