"""The world behind a motion's frames as job options (``render``, ``simulate --video``): the ground's
colours, the light and the sky of a :class:`shellsim.world.WorldLook`, declared alike by every job
through :func:`world_option`; :func:`look_of` is the look a scene file's ``[look]`` table sets, on which
:meth:`WorldSettings.over` lays the options a user changed."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

from shellsim.errors import SettingError
from shellsim.settings import float_list, floats, option
from shellsim.world import WorldLook

if TYPE_CHECKING:
    from shellsim.shot.spec import LookSpec

#: The options of :class:`WorldSettings`, declared by every job that renders a motion.
OPTIONS = ("ground_colors", "light", "sky")
_LOOK = WorldLook()


def _show(values) -> str:
    """Numbers as the options read them: ``"0.1,0.2,0.3"``."""
    return ",".join(f"{v:g}" for v in values)


_DEFAULTS = {
    "ground_colors": _LOOK.ground_colors[0] + _LOOK.ground_colors[1],
    "light": _LOOK.light,
    "sky": _LOOK.zenith + _LOOK.horizon,
}
#: The :class:`WorldLook` fields each option sets.
_FIELDS = {"ground_colors": ("ground_colors",), "light": ("light",), "sky": ("zenith", "horizon")}


@dataclass(frozen=True)
class WorldSettings:
    """The look of the world behind a motion's body, as options (defaults: :class:`WorldLook`'s)."""

    ground_colors: tuple[float, ...] = option(
        _DEFAULTS["ground_colors"],
        help="the ground checker's two colours R,G,B,R,G,B in [0, 1] (squares of 0.1 m)",
        parse=float_list,
        shown_default=_show(_DEFAULTS["ground_colors"]),
    )
    light: tuple[float, ...] = option(
        _DEFAULTS["light"],
        help="direction toward the light x,y,z in the world (z up); it casts the body's shadow",
        parse=floats(3),
        shown_default=_show(_DEFAULTS["light"]),
    )
    sky: tuple[float, ...] = option(
        _DEFAULTS["sky"],
        help="background R,G,B, or the sky's zenith and horizon R,G,B,R,G,B (a vertical gradient)",
        parse=float_list,
        shown_default=_show(_DEFAULTS["sky"]),
    )

    def __post_init__(self):
        for name, counts in (("ground_colors", (6,)), ("sky", (3, 6))):
            value = getattr(self, name)
            if len(value) not in counts or not all(0.0 <= v <= 1.0 for v in value):
                expected = " or ".join(map(str, counts))
                raise SettingError(name, f"expected {expected} numbers in [0, 1], got {value}")
        if len(self.light) != 3 or not any(self.light):
            raise SettingError("light", f"expected a non-zero direction x,y,z, got {self.light}")

    @classmethod
    def of(cls, settings) -> WorldSettings:
        """The world options of a job's ``settings``, which declare :data:`OPTIONS` (:func:`world_option`)."""
        return cls(**{name: getattr(settings, name) for name in OPTIONS})

    def changed(self) -> list[str]:
        """The options set to other than their defaults."""
        return [name for name in OPTIONS if tuple(getattr(self, name)) != _DEFAULTS[name]]

    def look(self, ground: bool = True) -> WorldLook:
        """The :class:`WorldLook` of these options, with the ground drawn or not."""
        return dataclasses.replace(
            _LOOK,
            ground=ground,
            ground_colors=(self.ground_colors[:3], self.ground_colors[3:]),
            light=self.light,
            zenith=self.sky[:3],
            horizon=self.sky[-3:],
        )

    def over(self, look: WorldLook) -> WorldLook:
        """``look`` with the options set to other than their defaults (:meth:`changed`) in place of its
        own."""
        mine = self.look(look.ground)
        return dataclasses.replace(
            look, **{f: getattr(mine, f) for name in self.changed() for f in _FIELDS[name]}
        )


def look_of(spec: LookSpec, ground: bool) -> WorldLook:
    """The :class:`WorldLook` of a scene file's ``[look]`` table ``spec``, with the ground drawn or not."""
    return WorldLook(
        ground=ground,
        square=spec.square,
        ground_colors=spec.ground_colors,
        light=spec.light,
        ambient=spec.ambient,
        diffuse=spec.diffuse,
        shadows=spec.shadows,
        zenith=spec.sky[0],
        horizon=spec.sky[-1],
        obstacle_color=spec.collider_color,
    )


def world_option(name: str):
    """A dataclass field for a job's settings: the option ``name`` of :class:`WorldSettings` (its help,
    parser and default), so that every job that renders a motion declares the same world options."""
    field = WorldSettings.__dataclass_fields__[name]
    return dataclasses.field(default=field.default, metadata=field.metadata)
