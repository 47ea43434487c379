"""The wind job: animate an asset's cage with the analytic wind of :mod:`shellsim.physics.wind` into a motion.

The body stands in the world of :mod:`shellsim.world` (metres, z up, ground at z = 0): its up axis turned
onto +z, its largest extent ``size`` metres, its lowest point on the ground, centred over the origin; an
absolute ``anchor`` rule is in those metres. :func:`wind` writes ``out`` (:mod:`shellsim.motion.format`:
world positions, the placement, settings :func:`shellsim.physics.wind.wind_settings`, the asset and its cage
by content digest). An existing ``out`` made with the same settings and cage is continued; one made
otherwise is refused (naming what changed) unless ``overwrite``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from shellsim.errors import SettingError
from shellsim.io.outputs import holds_outputs
from shellsim.motion.format import MAX_FPS, MAX_FRAMES
from shellsim.physics.selection import selection_text
from shellsim.physics.wind import RANGES, WindSettings, max_frequency
from shellsim.settings import check_range, check_required, floats, option, overwrite_option, resume_option
from shellsim.world import BODY_SIZE

log = logging.getLogger(__name__)


_W = WindSettings


@dataclass(frozen=True)
class WindJobSettings:
    """What :func:`wind` does. The wind's own settings (None: the default of
    :class:`~shellsim.physics.wind.WindSettings`) are its fields; ``margin`` picks a cage other than the
    stored one; ``size`` and an absolute ``anchor`` are world metres."""

    asset: str = option(help="asset directory or shipped asset name", required=True)
    frames: int = option(120, help="number of frames, the first at rest")
    fps: float = option(30.0, help="frames per second")
    strength: float | None = option(
        help="mean tip deflection / height, 0-1", shown_default=f"{_W.strength:g}"
    )
    direction: tuple[float, ...] | None = option(
        help="wind direction x,y,z", parse=floats(3), shown_default=",".join(f"{c:g}" for c in _W.direction)
    )
    gust: float | None = option(help="relative gust amplitude, 0-1", shown_default=f"{_W.gust:g}")
    frequency: float | None = option(
        help="gust frequency in Hz, at most fps / 6", shown_default=f"{_W.frequency:g}"
    )
    turbulence: float | None = option(
        help="relative turbulence amplitude, 0-1", shown_default=f"{_W.turbulence:g}"
    )
    size: float = option(BODY_SIZE, help="the body's largest extent in metres")
    anchor: str | None = option(
        help="fixed vertices as AXIS OP VALUE in world metres (z up, the body standing on the ground at "
        "z = 0) or in % of the cage's extent, as for 'simulate --pin': 'z<0.015', 'z<5%', 'y>0.1'",
        parse=selection_text,
        shown_default=f"the lowest {100 * _W.base_fraction:g}% of the cage along the asset's up axis",
    )
    seed: int | None = option(help="turbulence seed", shown_default=str(_W.seed))
    margin: float | None = option(
        help="dilation of the outer shell when the cage is built, relative to its diagonal",
        shown_default="the stored cage's, else 0.02",
    )
    out: str | None = option(help="motion file to write", shown_default="ASSETNAME_wind.npz")
    resume: bool = resume_option()
    overwrite: bool = overwrite_option()

    def __post_init__(self):
        check_required(self)
        check_range("frames", self.frames, 1, MAX_FRAMES, "an integer")
        check_range("size", self.size, 1e-3, 1e3, "a length in metres")
        check_range("fps", self.fps, 0, MAX_FPS, "a number of frames per second", "(]")
        for name, what in (
            ("strength", "a tip deflection / height"),
            ("gust", "a relative amplitude"),
            ("turbulence", "a relative amplitude"),
            ("seed", "an integer"),
        ):
            if getattr(self, name) is not None:
                check_range(name, getattr(self, name), *RANGES[name], what)
        frequency = _W.frequency if self.frequency is None else self.frequency
        low, high = RANGES["frequency"]
        top = max_frequency(self.fps)
        if not low <= frequency <= min(high, top):  # faster turbulence aliases
            raise SettingError(
                "frequency",
                f"expected a number of Hz in [{low:g}, {high:g}] and at most {top:.4g} (fps / "
                f"{self.fps / top:g}: faster turbulence would alias), got {frequency:g}",
            )
        if self.margin is not None:
            check_range("margin", self.margin, 0, 1, "a fraction of the shell's diagonal", "(]")
        if self.direction is not None and not math.hypot(*self.direction) > 0:
            raise SettingError("direction", "expected a non-zero vector")

    def wind_settings(self, up) -> WindSettings:
        """The :class:`shellsim.physics.wind.WindSettings` for an asset whose up axis is ``up`` (3,)."""
        names = ("strength", "direction", "gust", "frequency", "turbulence", "anchor", "seed")
        given = {k: getattr(self, k) for k in names if getattr(self, k) is not None}
        return WindSettings(up=tuple(float(c) for c in up), **given)


@dataclass
class WindResult:
    """out : the motion file; frames : its frame count; stats : its ``meta["stats"]``."""

    out: Path
    frames: int
    stats: dict


@holds_outputs
def wind(settings: WindJobSettings, progress: bool = True) -> WindResult:
    """Animate the asset of ``settings`` into its motion file (module docstring)."""
    from neural.asset import load_asset
    from shellsim.cage.build import CageConfig
    from shellsim.cage.store import load_or_build_cage
    from shellsim.io.outputs import check_writable_file, lock_output
    from shellsim.motion.format import cage_digest
    from shellsim.motion.writer import MotionWriter, motion_exists
    from shellsim.physics.wind import animate_wind, motion_changes, wind_settings
    from shellsim.world import UP, Placement, describe_placement, place_on_ground

    s = settings
    asset = load_asset(s.asset)
    wind_ = s.wind_settings(UP)
    out = check_writable_file(Path(s.out) if s.out else Path(f"{asset.name}_wind.npz"), "out")
    lock_output(out, "out")
    # the stored cage whatever its settings (unless margin asks for another), else a default one
    cage = load_or_build_cage(asset, None if s.margin is None else CageConfig(margin=s.margin))
    if motion_exists(out) and not s.overwrite:
        replace = "give {overwrite} to start it anew, or another {out}"
        writer = MotionWriter.resume(out)  # not a motion file: refused as it is, never replaced
        if writer.motion.producer != "shellsim wind":
            raise SettingError("out", f"not a 'shellsim wind' motion file; {replace}", out)
        writer.motion.check_against(cage)
        if not writer.motion.placement:
            raise SettingError(
                "out", f"was made by an earlier shellsim in the asset's own units, not metres; {replace}", out
            )
        changes = motion_changes(writer.motion, wind_settings(wind_, s.fps))
        made = Placement.from_dict(writer.motion.placement, str(out)).scale
        placement = place_on_ground(cage.vertices, asset.up, s.size)
        if not math.isclose(made, placement.scale, rel_tol=1e-9):
            changes.append(f"{{size}}: {s.size * made / placement.scale:g} -> {s.size:g}")
        if changes:
            raise SettingError("out", f"made with other settings ({'; '.join(changes)}); {replace}", out)
        rest = writer.motion.rest_vertices
        log.info("continuing %s after frame %d", out, writer.n_frames - 1)
    else:
        if out.exists():
            log.info("--overwrite: replacing %s", out)
        elif s.resume:
            log.info("%s does not exist: nothing to resume, starting it", out)
        placement = place_on_ground(cage.vertices, asset.up, s.size)
        rest = placement.to_world(cage.vertices)
        log.info("%s", describe_placement(asset.name, placement, rest))
        record = {"name": asset.name, "digest": asset.digest()}
        writer = MotionWriter(
            out,
            rest,
            cage.tets,
            {
                "up": list(UP),
                "units": "metres: positions and rest_vertices in the world (z up, ground z = 0)",
            },
            producer="shellsim wind",
            asset=record,
            placement=placement.as_dict(),
            cage_digest=cage_digest(cage.vertices, cage.tets),
        )
    with writer:
        animate_wind(rest, cage.tets, wind_, s.frames, s.fps, writer, progress=progress)
    return WindResult(out, writer.n_frames, dict(writer.motion.meta.get("stats", {})))
