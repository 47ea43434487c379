"""The wind job: animate an asset's cage with the analytic wind of :mod:`shellsim.physics.wind` into a motion.

No simulation: every frame is the closed-form displacement of a cantilever in the wind, as far as it keeps
every tet valid. The body stands in the world of :mod:`shellsim.world` (metres, z up, ground at z = 0): its
up axis turned onto +z, its largest extent ``size`` metres, its lowest point on the ground, centred over the
origin; an absolute ``anchor`` rule is in those metres. :func:`wind` records ``out``
(:mod:`shellsim.jobs.recording`; :mod:`shellsim.motion.format`: world positions, the placement, settings
:func:`shellsim.physics.wind.wind_record`, the asset and its cage by content digest). An existing ``out``
made with the same settings and cage is continued; one made otherwise is refused (naming what changed)
unless ``overwrite``.
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
from shellsim.physics.wind import RANGES, WindField, max_frequency
from shellsim.settings import check_range, check_required, floats, option, overwrite_option, resume_option
from shellsim.world import BODY_SIZE

log = logging.getLogger(__name__)

PRODUCER = "shellsim wind"


_W = WindField


@dataclass(frozen=True)
class WindSettings:
    """What :func:`wind` does. The wind's own settings (None: the default of
    :class:`~shellsim.physics.wind.WindField`) are its fields; ``margin`` picks a cage other than the
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

    def field(self, up) -> WindField:
        """The :class:`shellsim.physics.wind.WindField` for an asset whose up axis is ``up`` (3,)."""
        names = ("strength", "direction", "gust", "frequency", "turbulence", "anchor", "seed")
        given = {k: getattr(self, k) for k in names if getattr(self, k) is not None}
        return WindField(up=tuple(float(c) for c in up), **given)


@dataclass
class WindResult:
    """out : the motion file; frames : its frame count; stats : its ``meta["stats"]``."""

    out: Path
    frames: int
    stats: dict


@dataclass
class WindFrame:
    """One wind frame: ``scale`` of its bending (below 1 where the full bend would fold the cage) and its
    smallest tet volume ratio."""

    scale: float
    volume_ratio: float

    def figures(self) -> dict[str, float]:
        return {
            "limited_frames": int(self.scale < 1),
            "min_bend_scale": self.scale,
            "min_volume_ratio": self.volume_ratio,
        }


@holds_outputs
def wind(settings: WindSettings, progress: bool = True) -> WindResult:
    """Animate the asset of ``settings`` into its motion file (module docstring)."""
    import numpy as np

    from neural.asset import load_asset
    from shellsim.io.outputs import check_writable_file, lock_output
    from shellsim.jobs.recording import REPLACE, record_frames, resume_or_refuse
    from shellsim.motion.writer import MotionWriter
    from shellsim.physics.wind import SETTING_NAMES, limited_wind_displacement, wind_record
    from shellsim.tetcage.build import CageConfig
    from shellsim.tetcage.geometry import MIN_VOLUME_RATIO, cage_digest
    from shellsim.tetcage.store import load_or_build_cage
    from shellsim.world import UP, Placement, describe_placement, place_on_ground

    s = settings
    asset = load_asset(s.asset)
    field = s.field(UP)
    out = check_writable_file(Path(s.out) if s.out else Path(f"{asset.name}_wind.npz"), "out")
    lock_output(out, "out")
    # the stored cage whatever its settings (unless margin asks for another), else a default one
    cage = load_or_build_cage(asset, None if s.margin is None else CageConfig(margin=s.margin))
    placement = place_on_ground(cage.vertices, asset.up, s.size)
    rest = placement.to_world(cage.vertices)
    record = wind_record(field, s.fps)
    writer = resume_or_refuse(out, PRODUCER, record, s.overwrite, s.resume, SETTING_NAMES)
    if writer is not None:
        writer.motion.check_against(cage)
        if not writer.motion.placement:
            raise SettingError(
                "out", f"was made by an earlier shellsim in the asset's own units, not metres; {REPLACE}", out
            )
        made = Placement.from_dict(writer.motion.placement, str(out)).scale
        if not math.isclose(made, placement.scale, rel_tol=1e-9):
            change = f"{{size}}: {s.size * made / placement.scale:g} -> {s.size:g}"
            raise SettingError("out", f"made with other settings ({change}); {REPLACE}", out)
    else:
        log.info("%s", describe_placement(asset.name, placement, rest))
        writer = MotionWriter(
            out,
            rest,
            cage.tets,
            {
                "up": list(UP),
                "units": "metres: positions and rest_vertices in the world (z up, ground z = 0)",
            },
            producer=PRODUCER,
            settings=record,
            asset={"name": asset.name, "digest": asset.digest()},
            placement=placement.as_dict(),
            cage_digest=cage_digest(cage.vertices, cage.tets),
        )
    made = {}

    def advance() -> WindFrame:
        t = writer.n_frames / s.fps
        u, scale, ratio = limited_wind_displacement(rest, cage.tets, t, field)
        made["frame"] = (rest + u, t, None)
        return WindFrame(scale, ratio)

    with writer:
        history = record_frames(
            writer,
            s.frames,
            advance,
            lambda: made["frame"],
            advice=str,
            desc="wind",
            progress=progress,
            initial=False,
        )
    stats = dict(writer.motion.meta.get("stats", {}))
    limited = [f.scale for f in history if f.scale < 1]
    if limited:
        log.warning(
            "the wind would fold the cage in %d frames: their bending was scaled down (to %.0f%% at worst) "
            "to keep every tet's volume ratio >= %g; a lower strength, gust or turbulence avoids it",
            len(limited),
            100 * float(np.min(limited)),
            MIN_VOLUME_RATIO,
        )
    return WindResult(out, writer.n_frames, stats)
