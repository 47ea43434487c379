"""Re-extract an asset's adaptive shells (Procedure 2) with other level-set parameters.

Settings left unset keep the values the asset was extracted with (its ``asset.json``); the new shells
replace the old ones, whose metrics move aside (:func:`neural.asset.replace_shells`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from neural.config import NarrowBandConfig, ShellConfig
from neural.device import DEVICES
from shellsim.errors import SettingError
from shellsim.io.outputs import holds_outputs
from shellsim.settings import check_choice, check_required, config_bounds, device_setting, option

log = logging.getLogger(__name__)

THE_ASSETS = "the asset's"
#: The settings that are fields of :class:`~neural.config.ShellConfig`.
SHELL_FIELDS = ("resolution", "steps", "beta_d", "sigma_min", "beta_e", "v_max", "min_part_fraction")
#: The config field each setting sets: its bound (:mod:`neural.config`) is the setting's.
CONFIG_FIELDS = {(ShellConfig, name): name for name in SHELL_FIELDS}
CONFIG_FIELDS[NarrowBandConfig, "max_peel"] = "max_peel"


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
        check_required(self)
        with config_bounds(self, CONFIG_FIELDS):
            ShellConfig(**self.shell_overrides())  # each bound is on one parameter alone
            if self.max_peel is not None:
                NarrowBandConfig(max_peel=self.max_peel)
        check_choice("device", self.device, DEVICES)

    def shell_overrides(self) -> dict:
        """The shell parameters that are set: {ShellConfig field: value}."""
        return {name: getattr(self, name) for name in SHELL_FIELDS if getattr(self, name) is not None}


@dataclass(frozen=True)
class ExtractResult:
    """The new shells of :func:`extract`: ``asset`` the asset directory they were written to,
    ``outer_faces`` and ``inner_faces`` the triangles of M+ and M-, ``width_mean``, ``width_median`` and
    ``width_max`` the distance from M+ to M- (world units; NaN when M- is empty), ``seconds`` the
    extraction's wall time."""

    asset: Path
    outer_faces: int
    inner_faces: int
    width_mean: float
    width_median: float
    width_max: float
    seconds: float


def asset_shell_config(asset, overrides: dict) -> ShellConfig:
    """The :class:`ShellConfig` the asset's shells were extracted with (its ``asset.json``), ``overrides``
    {field: value} replacing some; a :class:`SettingError` of ``asset`` when they do not make one."""
    known = {f.name for f in dataclasses.fields(ShellConfig)}
    stored = {k: v for k, v in asset.meta.get("shell", {}).items() if k in known}
    try:
        return ShellConfig(**{**stored, **overrides})
    except (TypeError, ValueError) as err:
        raise SettingError("asset", f"shell parameters: {err}", value=asset.root) from None


@holds_outputs
def extract(settings: ExtractSettings) -> ExtractResult:
    """Extract the shells of ``settings.asset`` again and replace its shell files."""
    from neural.asset import command_line, load_asset, load_field, refuse_shipped, replace_shells
    from neural.shell.from_field import extract_field_shells
    from shellsim.io.outputs import check_writable_dir, lock_output
    from shellsim.memory import check_memory, shell_bytes

    asset = load_asset(settings.asset)
    refuse_shipped(asset, "extract")
    lock_output(check_writable_dir(asset.root, "asset"), "asset")  # new shells and asset.json go there
    device = device_setting(settings.device)
    config = asset_shell_config(asset, settings.shell_overrides())
    grid = f"a shell grid of {config.resolution}^3 nodes"
    check_memory("resolution", shell_bytes(config.resolution), grid, "to extract the shells", device)
    if settings.max_peel is not None:
        narrowband = dataclasses.replace(asset.narrowband_config(), max_peel=settings.max_peel)
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
    result = ExtractResult(asset=Path(asset.root), seconds=time.perf_counter() - start, **shells.stats)
    log.info(
        "%s: new shells in %.1f s: M+ %d faces, M- %d faces, mean width %.4g",
        result.asset,
        result.seconds,
        result.outer_faces,
        result.inner_faces,
        result.width_mean,
    )
    return result
