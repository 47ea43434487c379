"""Re-extract an asset's adaptive shells (Procedure 2) with other level-set parameters.

Settings left unset keep the values the asset was extracted with (its ``asset.json``); the new shells
replace the old ones, whose metrics move aside (:func:`neural.asset.replace_shells`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass

from neural.config import ShellConfig
from neural.device import DEVICES
from shellsim.errors import SettingError
from shellsim.settings import check_choice, device_setting, option

log = logging.getLogger(__name__)

THE_ASSETS = "the asset's"


@dataclass(frozen=True)
class ExtractSettings:
    """What ``shellsim extract`` takes; None keeps the asset's value."""

    asset: str = option(help="shipped asset name or asset directory", required=True)
    resolution: int | None = option(help="grid samples per axis", shown_default=THE_ASSETS)
    steps: int | None = option(help="level-set steps T (paper: 50)", shown_default=THE_ASSETS)
    beta_d: float | None = option(
        help="dilation speed per unit voxel opacity (Eq. 6)", shown_default=THE_ASSETS
    )
    sigma_min: float | None = option(
        help="voxel opacity below which dilation stops (Eq. 6)", shown_default=THE_ASSETS
    )
    beta_e: float | None = option(help="erosion speed coefficient (Eq. 7)", shown_default=THE_ASSETS)
    v_max: float | None = option(help="speed cap, voxels per unit time", shown_default=THE_ASSETS)
    min_part_fraction: float | None = option(
        help="drop M+ parts smaller than this fraction of the largest (0 keeps all)", shown_default=THE_ASSETS
    )
    max_peel: int | None = option(
        help="also set the depth-peeling cap dp_max of the asset's narrow-band renderer",
        shown_default=THE_ASSETS,
    )
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        for name, value in self.shell_overrides().items():
            try:
                ShellConfig(**{name: value})  # each bound is on one parameter alone
            except ValueError as err:
                raise SettingError(name, f"shell parameters: {err}") from None
        check_choice("device", self.device, DEVICES)

    def shell_overrides(self) -> dict:
        """The shell parameters that are set: {ShellConfig field: value}."""
        names = ("resolution", "steps", "beta_d", "sigma_min", "beta_e", "v_max", "min_part_fraction")
        return {name: getattr(self, name) for name in names if getattr(self, name) is not None}


def extract(settings: ExtractSettings) -> dict:
    """Extract the shells of ``settings.asset`` again and replace its shell files; returns the shells'
    statistics (faces of M+ and M-, widths) with ``seconds``, the extraction's wall time."""
    from neural.asset import command_line, load_asset, load_field, refuse_shipped, replace_shells
    from neural.shell.from_field import extract_field_shells
    from shellsim.io.outputs import check_writable_dir

    asset = load_asset(settings.asset)
    refuse_shipped(asset, "extract")
    check_writable_dir(asset.root, "asset")  # new shells and asset.json are written there
    device = device_setting(settings.device)
    known = {f.name for f in dataclasses.fields(ShellConfig)}
    stored = {k: v for k, v in asset.meta.get("shell", {}).items() if k in known}
    try:
        config = ShellConfig(**{**stored, **settings.shell_overrides()})
    except (TypeError, ValueError) as err:
        raise SettingError("asset", f"shell parameters: {err}", value=asset.root) from None
    if settings.max_peel is not None:
        try:
            narrowband = dataclasses.replace(asset.narrowband_config(), max_peel=settings.max_peel)
        except ValueError as err:
            raise SettingError("max_peel", str(err)) from None
        asset.meta["narrowband"] = dataclasses.asdict(narrowband)
    field = load_field(asset, device)
    start = time.perf_counter()
    shells = extract_field_shells(field, config, device)
    replace_shells(
        asset,
        shells.outer,
        shells.inner,
        {**dataclasses.asdict(config), **shells.stats, "command": command_line()},
    )
    stats = {**shells.stats, "seconds": time.perf_counter() - start}
    log.info(
        "%s: new shells in %.1f s: M+ %d faces, M- %d faces, mean width %.4g",
        asset.root,
        stats["seconds"],
        stats["outer_faces"],
        stats["inner_faces"],
        stats.get("width_mean", float("nan")),
    )
    return stats
