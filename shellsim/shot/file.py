"""Read a scene file (TOML, the schema in docs/scene-file.md) into a :class:`~shellsim.shot.spec.SceneSpec`.

Every key is known, typed and in its domain, every name unique and every reference and path resolved (paths
relative to the scene file's directory); nothing heavy is loaded (an asset is only found). Each problem is
one :class:`SceneError` line, ``FILE: [table] key: problem`` or ``FILE: [[body]] #2 (NAME) key: problem``;
the checks that need loaded cages (overlapping bodies, a region that selects nothing) come later and report
through :func:`problem` with the spec's ``where``.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

from neural.asset import resolve_asset, shipped_assets_dir
from neural.errors import InputError
from shellsim.physics.materials import PRESETS, RANGES
from shellsim.physics.selection import parse_selection
from shellsim.shot.spec import (
    RGB,
    ActionSpec,
    BodySpec,
    CageSpec,
    CameraKeyframe,
    CameraSpec,
    ColliderSpec,
    Keyframe,
    LookSpec,
    SceneError,
    SceneSpec,
    Vec3,
    WorldSpec,
)
from shellsim.world import CAMERA_PRESETS, INTEGRATORS, UNITS

if TYPE_CHECKING:
    from neural.data import Cameras

_Bounds = tuple[float, float, str]  # (low, high, ends): ends "[]", "(]", "[)" or "()" include or exclude each
_ANY: _Bounds = (-math.inf, math.inf, "()")
_POSITIVE: _Bounds = (0.0, math.inf, "()")
_NON_NEGATIVE: _Bounds = (0.0, math.inf, "[)")
_FRICTION: _Bounds = (0.0, 10.0, "[]")
_FRACTION: _Bounds = (0.0, 1.0, "[]")
_REQUIRED = object()  # the default of a key that must be given

#: The tables of a scene file: name -> whether it is an array of tables.
TABLES = {"world": False, "body": True, "collider": True, "action": True, "camera": True, "look": False}
WORLD_KEYS = (
    "fps",
    "duration",
    "frames",
    "substeps",
    "gravity",
    "ground",
    "ground_friction",
    "damping",
    "drag",
    "contact_gap",
    "friction_velocity",
    "settle",
    "integrator",
)
BODY_KEYS = (
    "name",
    "size",
    "position",
    "rotation",
    "material",
    "youngs",
    "poisson",
    "density",
    "damping",
    "friction",
    "velocity",
    "spin",
    "color",
    "cage",
)
BODY_KINDS = {"asset": ("asset", "up"), "mesh": ("mesh", "units")}
COLLIDER_KEYS = ("name", "shape", "position", "rotation", "friction", "color")
COLLIDER_KINDS = {"box": ("half_extents",), "sphere": ("radius",), "mesh": ("mesh", "units", "scale")}
ACTION_KEYS = ("kind", "start", "end", "body")
ACTION_KINDS = {
    "pin": ("region",),
    "grab": ("region", "keyframes"),
    "push": ("region", "velocity", "force"),
    "wind": ("speed", "direction", "gust", "gust_frequency", "turbulence", "drag_coefficient"),
}
CAMERA_KEYS = ("name", "kind", "fov")
CAMERA_KINDS = {
    "orbit": ("target", "distance", "elevation", "azimuth", "degrees"),
    "fixed": ("position", "target"),
    "follow": ("position", "body"),
    "path": ("keyframes",),
    "capture": ("path", "smooth", "body"),
    **{name: ("elevation",) if elevation is None else () for name, (_, elevation) in CAMERA_PRESETS.items()},
}
LOOK_KEYS = ("ground_colors", "square", "light", "ambient", "diffuse", "shadows", "sky", "collider_color")
MAX_FPS = 1000.0
MAX_FRAMES = 10000
MAX_SUBSTEPS = 1000
MAX_CONTACT_GAP = 0.1  # [m]
MAX_SETTLE = 60.0  # [s]
MIN_TARGET_TETS = 10  # shellsim.tetcage.build.CageConfig's bound


def problem(where: str, key: str | None, message: str) -> SceneError:
    """The :class:`SceneError` ``WHERE KEY: MESSAGE`` (``WHERE: MESSAGE`` without a key): ``where`` is a
    spec's ``where`` (``FILE: [[body]] #2 (lego)``, ``FILE: [world]``) or the file's path."""
    return SceneError(f"{where} {key}: {message}" if key else f"{where}: {message}")


def read_scene(path: str | os.PathLike) -> SceneSpec:
    """The scene file ``path``, read and checked: a :class:`SceneSpec` with every default filled in.

    Any problem (the file unreadable or not TOML, an unknown table or key, a wrong type, a value out of its
    range, a missing or unknown name, asset or mesh file, ...) is a one-line :class:`SceneError` that starts
    with ``path`` as given and names the table and the key."""
    shown = str(path)
    resolved = Path(path).resolve()
    data = _load(resolved, shown)
    for name, value in data.items():
        _check_table(shown, name, value)
    if not data.get("body"):
        raise problem(f"{shown}: [[body]]", None, "missing; a scene needs at least one body")
    world = _world(_Table(data.get("world", {}), f"{shown}: [world]"))
    names: dict[str, str] = {}  # bodies' and colliders' names -> where each is
    base = resolved.parent
    bodies = tuple(_body(t, world, base) for t in _entries(data, "body", shown, names))
    colliders = tuple(_collider(t, base) for t in _entries(data, "collider", shown, names))
    known = {b.name for b in bodies}
    actions = tuple(_action(t, world, known, names) for t in _entries(data, "action", shown))
    cameras = tuple(_camera(t, bodies, names, base) for t in _entries(data, "camera", shown, {}))
    look = _look(_Table(data.get("look", {}), f"{shown}: [look]"))
    return SceneSpec(str(resolved), world, bodies, colliders, actions, cameras, look)


def _load(path: Path, shown: str) -> dict:
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise problem(shown, None, f"cannot read the scene file ({err.strerror or err})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise problem(
            shown, None, f"not UTF-8 text (byte {raw[err.start]:#04x} at offset {err.start})"
        ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise problem(shown, None, f"not valid TOML: {err}") from None


def _check_table(shown: str, name: str, value) -> None:
    """``name = value`` at the top of the file must be one of :data:`TABLES`, in its form."""
    if name not in TABLES:
        many = isinstance(value, list) and all(isinstance(v, dict) for v in value)
        label = f"[[{_key(name)}]]" if many else f"[{_key(name)}]" if isinstance(value, dict) else _key(name)
        what = "key outside any table" if label == _key(name) else "table"
        raise problem(shown, None, f"{label}: unknown {what}" + _suggest(name, TABLES, _table))
    many = TABLES[name]
    if many and not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
        raise problem(
            f"{shown}: [[{name}]]", None, f"expected an array of tables [[{name}]], got {_shown(value)}"
        )
    if not many and not isinstance(value, dict):
        raise problem(f"{shown}: [{name}]", None, f"expected a table [{name}], got {_shown(value)}")


def _entries(data: dict, table: str, shown: str, names: dict[str, str] | None = None) -> list[_Table]:
    """The ``[[table]]`` entries, each with its ``where`` (``FILE: [[table]] #k (NAME)``); with ``names``,
    each entry's ``name`` (default ``tablek``), unique across ``names``, which it joins."""
    out = []
    for k, entry in enumerate(data.get(table, []), 1):
        t = _Table(entry, f"{shown}: [[{table}]] #{k}", noun=table)
        t.name = t.choice("kind", _REQUIRED, ACTION_KINDS) if names is None else t.text("name", f"{table}{k}")
        t.where += f" ({t.name})"
        if names is not None:
            if t.name in names:
                raise t.error("name", f"{t.name!r} is already the name of {names[t.name]}")
            names[t.name] = f"[[{table}]] #{k}"
        out.append(t)
    return out


class _Table:
    """A TOML table being read: its ``data``, ``where`` it is (``FILE: [table]``), the ``prefix`` of its
    keys in messages (``cage.`` for ``[body.cage]``); an entry of ``[[noun]]`` also has its ``name``."""

    def __init__(self, data: dict, where: str, prefix: str = "", noun: str = ""):
        self.data, self.where, self.prefix, self.noun = data, where, prefix, noun
        self.name = ""

    def error(self, key: str, message: str) -> SceneError:
        return problem(self.where, self.prefix + key, message)

    def keys(self, common: tuple[str, ...], kinds: dict[str, tuple[str, ...]] | None = None, kind: str = ""):
        """Refuse a key outside ``common`` and ``kinds[kind]`` (the keys of each kind of this table's
        entries): a key of another kind says whose it is, an unknown key suggests the closest known one."""
        kinds = kinds or {}
        for key in self.data:
            if key in common + kinds.get(kind, ()):
                continue
            owners = [k for k, keys in kinds.items() if key in keys]
            if owners:
                others = f"{_a(owners[0])} {'/'.join(owners)} {self.noun}"
                raise self.error(key, f"not a key of {_a(kind)} {kind} {self.noun}, only of {others}")
            everything = list(dict.fromkeys(common + sum(kinds.values(), ())))
            raise self.error(_key(key), "unknown key" + _suggest(key, everything, str))

    def _get(self, key: str, default):
        """(present, value): the raw value, or ``default`` when absent (an error when it is required)."""
        if key in self.data:
            return True, self.data[key]
        if default is _REQUIRED:
            raise self.error(key, "missing")
        return False, default

    def number(self, key: str, default, bounds: _Bounds = _ANY) -> float | None:
        present, value = self._get(key, default)
        if not present:
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"expected a number, got {_shown(value)}")
        if not math.isfinite(value):
            raise self.error(key, f"expected a finite number, got {_shown(value)}")
        return float(self._within(key, value, bounds))

    def integer(self, key: str, default, bounds: _Bounds) -> int | None:
        present, value = self._get(key, default)
        if present and (isinstance(value, bool) or not isinstance(value, int)):
            raise self.error(key, f"expected an integer, got {_shown(value)}")
        return self._within(key, value, bounds) if present else value

    def flag(self, key: str, default: bool) -> bool:
        present, value = self._get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {_shown(value)}")
        return value

    def text(self, key: str, default) -> str | None:
        present, value = self._get(key, default)
        if present and not (isinstance(value, str) and value and value.isprintable()):
            raise self.error(key, f"expected a non-empty string of printable characters, got {_shown(value)}")
        return value

    def choice(self, key: str, default, choices) -> str:
        value = self.text(key, default)
        if value not in choices:
            raise self.error(key, f"{value!r} is not one of {', '.join(choices)}" + _suggest(value, choices))
        return value

    def vector(self, key: str, default) -> Vec3 | None:
        present, value = self._get(key, default)
        if not present:
            return value
        if not (isinstance(value, list) and len(value) == 3):
            raise self.error(key, f"expected 3 numbers [x, y, z], got {_shown(value)}")
        if any(isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) for v in value):
            raise self.error(key, f"expected 3 finite numbers [x, y, z], got {_shown(value)}")
        return tuple(float(v) for v in value)

    def colors(self, key: str, default, counts: tuple[int, ...]) -> tuple[RGB, ...]:
        """``key``: RGB colours in [0, 1], as many as one of ``counts``; one is written ``[r, g, b]``, several
        ``[[r, g, b], ...]``."""
        present, value = self._get(key, default)
        if not present:
            return value
        many = isinstance(value, list) and len(value) > 1 and not _numbers(value, 3)
        colors = value if many else [value]
        if not (len(colors) in counts and all(_numbers(c, 3) for c in colors)):
            shapes = " or ".join(
                "[r, g, b]" if n == 1 else f"[{', '.join(['[r, g, b]'] * n)}]" for n in counts
            )
            raise self.error(key, f"expected {shapes}, got {_shown(value)}")
        if not all(0 <= v <= 1 for c in colors for v in c):
            raise self.error(key, f"must all be in [0, 1], got {_shown(value)}")
        return tuple(tuple(float(v) for v in c) for c in colors)

    def _within(self, key: str, value, bounds: _Bounds):
        low, high, ends = bounds
        if (value > low if ends[0] == "(" else value >= low) and (
            value < high if ends[1] == ")" else value <= high
        ):
            return value
        span = (
            f"{'>' if ends[0] == '(' else '>='} {low:g}"
            if high == math.inf
            else f"in {ends[0]}{low:g}, {high:g}{ends[1]}"
        )
        raise self.error(key, f"must be {span}, got {_shown(value)}")


def _world(t: _Table) -> WorldSpec:
    d = WorldSpec()
    t.keys(WORLD_KEYS)
    fps = t.number("fps", d.fps, (0.0, MAX_FPS, "(]"))
    if "duration" in t.data and "frames" in t.data:
        raise t.error("frames", "give duration or frames, not both")
    if "duration" in t.data:
        duration = t.number("duration", _REQUIRED, _POSITIVE)
        frames = round(duration * fps)
        if not 1 <= frames <= MAX_FRAMES:
            raise t.error(
                "duration", f"{duration:g} s at {fps:g} fps is {frames} frames, not in [1, {MAX_FRAMES}]"
            )
    else:
        frames = t.integer("frames", d.frames, (1, MAX_FRAMES, "[]"))
    return WorldSpec(
        fps=fps,
        frames=frames,
        substeps=t.integer("substeps", d.substeps, (1, MAX_SUBSTEPS, "[]")),
        gravity=t.number("gravity", d.gravity, _NON_NEGATIVE),
        ground=t.flag("ground", d.ground),
        ground_friction=t.number("ground_friction", d.ground_friction, _FRICTION),
        damping=t.number("damping", d.damping, _NON_NEGATIVE),
        drag=t.number("drag", d.drag, _NON_NEGATIVE),
        contact_gap=t.number("contact_gap", d.contact_gap, (0.0, MAX_CONTACT_GAP, "(]")),
        friction_velocity=t.number("friction_velocity", d.friction_velocity, _POSITIVE),
        settle=t.number("settle", d.settle, (0.0, MAX_SETTLE, "[]")),
        integrator=t.choice("integrator", d.integrator, INTEGRATORS),
    )


def _look(t: _Table) -> LookSpec:
    d = LookSpec()
    t.keys(LOOK_KEYS)
    light = t.vector("light", d.light)
    if not any(light):
        raise t.error("light", f"must not be zero, got {_shown(t.data['light'])}")
    return LookSpec(
        ground_colors=t.colors("ground_colors", d.ground_colors, (2,)),
        square=t.number("square", d.square, _POSITIVE),
        light=light,
        ambient=t.number("ambient", d.ambient, _NON_NEGATIVE),
        diffuse=t.number("diffuse", d.diffuse, _NON_NEGATIVE),
        shadows=t.flag("shadows", d.shadows),
        sky=t.colors("sky", d.sky, (1, 2)),
        collider_color=t.colors("collider_color", (d.collider_color,), (1,))[0],
    )


def _body(t: _Table, world: WorldSpec, base: Path) -> BodySpec:
    d = BodySpec(name=t.name)
    given = [key for key in BODY_KINDS if key in t.data]
    if len(given) != 1:
        raise t.error("asset", "give asset or mesh, not both" if given else "missing (or give a mesh)")
    kind = given[0]
    t.keys(BODY_KEYS, BODY_KINDS, kind)
    position = t.vector("position", d.position)
    if world.ground and position[2] < 0:
        raise t.error("position", f"z = {position[2]:g} m puts the body's bottom below the ground (z = 0)")
    material = {key: t.number(key, None, RANGES[key]) for key in ("youngs", "poisson", "density")}
    cage = t.data.get("cage", {})
    if not isinstance(cage, dict):
        raise t.error("cage", f"expected a table [body.cage], got {_shown(cage)}")
    c = _Table(cage, t.where, "cage.")
    c.keys(("target_tets", "margin"))
    return BodySpec(
        name=t.name,
        asset=_asset(t, base) if kind == "asset" else None,
        mesh=_mesh_file(t, base) if kind == "mesh" else None,
        units=t.choice("units", d.units, UNITS),
        size=t.number("size", d.size, _POSITIVE),
        position=position,
        rotation=t.vector("rotation", d.rotation),
        material=t.choice("material", d.material, PRESETS),
        **material,
        damping=t.number("damping", d.damping, _NON_NEGATIVE),
        friction=t.number("friction", d.friction, _FRICTION),
        velocity=t.vector("velocity", d.velocity),
        spin=t.vector("spin", d.spin),
        up=_up(t),
        color=t.colors("color", (None,), (1,))[0],
        cage=CageSpec(
            target_tets=c.integer("target_tets", None, (MIN_TARGET_TETS, math.inf, "[)")),
            margin=c.number("margin", None, _NON_NEGATIVE),
        ),
        where=t.where,
    )


def _up(t: _Table) -> Vec3 | None:
    """``up``: an asset's up axis in its own frame (turned onto the world's +z), not zero; None: the
    asset's."""
    up = t.vector("up", None)
    if up is not None and not math.hypot(*up) > 0:
        raise t.error("up", "must be a non-zero vector [x, y, z]")
    return up


def _asset(t: _Table, base: Path) -> str:
    """``asset``: a directory beside the scene file (its resolved path) or else a shipped asset (its name);
    found with :func:`neural.asset.resolve_asset` and its ``asset.json`` present, nothing loaded."""
    text = t.text("asset", _REQUIRED)
    local, shipped = base / text, shipped_assets_dir() / text
    by_name = Path(text).name == text and not local.is_dir() and shipped.is_dir()
    try:
        root, _ = resolve_asset(shipped if by_name else local)
    except InputError as err:
        raise t.error("asset", str(err)) from None
    if not (root / "asset.json").is_file():
        raise t.error("asset", f"{root} is not an asset (asset.json missing)")
    return text if by_name else str(root.resolve())


def _mesh_file(t: _Table, base: Path) -> str:
    """``mesh``: a file, relative to the scene file's directory; its resolved path."""
    path = (base / t.text("mesh", _REQUIRED)).resolve()
    if not path.is_file():
        raise t.error("mesh", f"no such file {path}")
    return str(path)


def _collider(t: _Table, base: Path) -> ColliderSpec:
    d = ColliderSpec(name=t.name, shape="box")
    shape = t.choice("shape", _REQUIRED, COLLIDER_KINDS)
    t.keys(COLLIDER_KEYS, COLLIDER_KINDS, shape)
    box, sphere, mesh = (shape == s for s in COLLIDER_KINDS)
    half_extents = t.vector("half_extents", _REQUIRED) if box else None
    if box and min(half_extents) <= 0:
        raise t.error("half_extents", f"must all be > 0, got {_shown(t.data['half_extents'])}")
    return ColliderSpec(
        name=t.name,
        shape=shape,
        position=t.vector("position", d.position),
        rotation=t.vector("rotation", d.rotation),
        half_extents=half_extents,
        radius=t.number("radius", _REQUIRED, _POSITIVE) if sphere else None,
        mesh=_mesh_file(t, base) if mesh else None,
        units=t.choice("units", d.units, UNITS),
        scale=t.number("scale", d.scale, _POSITIVE),
        friction=t.number("friction", d.friction, _FRICTION),
        color=t.colors("color", (None,), (1,))[0],
        where=t.where,
    )


def _action(t: _Table, world: WorldSpec, bodies: set[str], names: dict[str, str]) -> ActionSpec:
    kind = t.name
    d = ActionSpec(kind=kind, start=0.0, end=0.0)
    t.keys(ACTION_KEYS, ACTION_KINDS, kind)
    start = t.number("start", 0.0, _NON_NEGATIVE)
    if start >= world.duration:
        raise t.error("start", f"{start:g} s is not before the end of the shot ({world.duration:g} s)")
    push = kind == "push"
    end = t.number("end", _REQUIRED if push else world.duration)
    velocity, force = t.vector("velocity", None), t.vector("force", None)
    if push and (velocity is None) == (force is None):
        raise t.error(
            "velocity", "give velocity or force, not both" if velocity else "missing (or give a force)"
        )
    impulse = push and velocity is not None  # a velocity push may take no time
    if end < start or (end == start and not impulse):
        after = "at or after" if impulse else "after"
        raise t.error("end", f"{end:g} s must be {after} start ({start:g} s)")
    body = t.text("body", None if kind == "wind" else _REQUIRED)
    if body is not None:
        _check_body(t, body, bodies, names)
    direction = t.vector("direction", d.direction)
    if direction[2] != 0 or direction[:2] == (0.0, 0.0):
        raise t.error(
            "direction", f"must be horizontal and not zero, [x, y, 0], got {_shown(t.data['direction'])}"
        )
    return ActionSpec(
        kind=kind,
        start=start,
        end=end,
        body=body,
        region=_region(t),
        keyframes=_keyframes(t, start, end) if kind == "grab" else (),
        velocity=velocity,
        force=force,
        speed=t.number("speed", _REQUIRED, _POSITIVE) if kind == "wind" else d.speed,
        direction=direction,
        gust=t.number("gust", d.gust, _FRACTION),
        gust_frequency=t.number("gust_frequency", d.gust_frequency, (0.0, 10.0, "[]")),
        turbulence=t.number("turbulence", d.turbulence, _FRACTION),
        drag_coefficient=t.number("drag_coefficient", d.drag_coefficient, (0.0, 10.0, "(]")),
        where=t.where,
    )


def _check_body(t: _Table, name: str, bodies: set[str], names: dict[str, str]) -> None:
    """``name`` (the ``body`` key) must be a body's; ``names``: the bodies' and colliders' names."""
    if name in bodies:
        return
    if name in names:
        raise t.error("body", f"{name!r} is {names[name]}, not a body")
    raise t.error("body", f"no body named {name!r}" + _suggest(name, sorted(bodies), repr))


def _region(t: _Table) -> tuple[str, ...]:
    """``region``: a rule of :mod:`shellsim.physics.selection` or an array of them, each parsed."""
    value = t.data.get("region", [])
    rules = [value] if isinstance(value, str) else value
    if not (isinstance(rules, list) and all(isinstance(r, str) and r.isprintable() for r in rules)):
        raise t.error("region", f"expected a rule such as 'z<10%' or an array of them, got {_shown(value)}")
    for rule in rules:
        try:
            parse_selection(rule)
        except InputError as err:
            raise t.error("region", str(err)) from None
    return tuple(rules)


def _keyframes(t: _Table, start: float, end: float) -> tuple[Keyframe, ...]:
    """A grab's ``keyframes``: times in (start, end], increasing."""
    value = t.data.get("keyframes")
    if value is None:
        raise t.error("keyframes", "missing (a grab moves along its keyframes)")
    if not (isinstance(value, list) and value and all(isinstance(v, dict) for v in value)):
        raise t.error(
            "keyframes",
            f"expected an array of tables {{time = .., position = [..]}}, got {_shown(value)}",
        )
    frames: list[Keyframe] = []
    for k, entry in enumerate(value, 1):
        f = _Table(entry, t.where, f"keyframes #{k} ")
        f.keys(("time", "position", "rotation"))
        earliest = frames[-1].time if frames else start
        time = f.number("time", _REQUIRED)
        if not earliest < time <= end:
            before = f"keyframe #{k - 1} ({earliest:g} s)" if frames else f"start ({start:g} s)"
            raise f.error("time", f"{time:g} s must be after {before} and at most end ({end:g} s)")
        d = Keyframe(time)
        frames.append(Keyframe(time, f.vector("position", d.position), f.vector("rotation", d.rotation)))
    return tuple(frames)


def _camera(t: _Table, bodies: tuple[BodySpec, ...], names: dict[str, str], base: Path) -> CameraSpec:
    d = CameraSpec(name=t.name)
    kind = t.choice("kind", d.kind, CAMERA_KINDS)
    t.keys(CAMERA_KEYS, CAMERA_KINDS, kind)
    position = t.vector("position", _REQUIRED if kind in ("fixed", "follow") else None)
    target = t.vector("target", d.target)
    if target is not None and target == position:
        raise t.error("target", "must differ from position")
    body = t.text("body", _REQUIRED if kind == "follow" else None)
    if body is not None:
        _check_body(t, body, {b.name for b in bodies}, names)
    capture = kind == "capture"
    if capture:
        body = _capture_body(t, body, bodies)
    return CameraSpec(
        name=t.name,
        kind=kind,
        position=position,
        target=target,
        distance=t.number("distance", d.distance, _POSITIVE),
        elevation=t.number("elevation", d.elevation, (-90.0, 90.0, "[]")),
        azimuth=t.number("azimuth", d.azimuth),
        degrees=t.number("degrees", d.degrees, (-3600.0, 3600.0, "[]")),
        fov=t.number("fov", None if capture else d.fov, (0.0, 180.0, "()")),
        body=body,
        keyframes=_camera_keyframes(t) if kind == "path" else (),
        path=_capture_file(t, base) if capture else None,
        smooth=t.number("smooth", d.smooth, _NON_NEGATIVE),
        where=t.where,
    )


def _capture_body(t: _Table, name: str | None, bodies: tuple[BodySpec, ...]) -> str:
    """A capture camera's ``body`` (``name``, a body's; None: the file's first asset body): an asset body,
    in whose asset's frame the capture's cameras are."""
    assets = [b.name for b in bodies if b.asset is not None]
    if name is None and not assets:
        raise t.error("body", "missing: no [[body]] is an asset, in whose frame a capture's cameras are")
    if name is not None and name not in assets:
        raise t.error("body", f"{name!r} is a mesh body; a capture's cameras are in an asset's frame")
    return assets[0] if name is None else name


def _capture_file(t: _Table, base: Path) -> str:
    """A capture camera's ``path``: a camera file or dataset directory, relative to the scene file's
    directory, that :func:`capture_cameras` reads; its resolved path."""
    path = (base / t.text("path", _REQUIRED)).resolve()
    if not path.exists():
        raise t.error("path", f"no such file or directory {path}")
    try:
        capture_cameras(path, 2, 2)  # any size: the file is only read and its cameras counted
    except InputError as err:
        raise t.error("path", str(err)) from None
    return str(path)


def capture_cameras(path, width: int, height: int) -> Cameras:
    """The cameras of the camera file or dataset directory ``path`` (:func:`neural.data.load_camera_file`:
    their order, the asset's frame), imaging ``width`` x ``height`` pixels (each keeps its horizontal field
    of view); an :class:`InputError` naming ``path`` when it cannot be read or lists fewer than 2. A capture
    camera's file, checked here and followed by :func:`shellsim.film.cameras.scene_shot`."""
    from neural.data import load_camera_file

    cameras = load_camera_file(path, width, height)
    if len(cameras) < 2:
        raise InputError(f"{path}: lists {len(cameras)} camera; a capture camera moves along at least 2")
    return cameras


def _camera_keyframes(t: _Table) -> tuple[CameraKeyframe, ...]:
    """A path camera's ``keyframes``: at least 2, times >= 0 and increasing, each target apart from its
    position."""
    value = t.data.get("keyframes")
    if value is None:
        raise t.error("keyframes", "missing (a path camera moves along its keyframes)")
    if not (isinstance(value, list) and len(value) >= 2 and all(isinstance(v, dict) for v in value)):
        raise t.error(
            "keyframes",
            "expected an array of at least 2 tables {time = .., position = [..], target = [..]}, "
            f"got {_shown(value)}",
        )
    frames: list[CameraKeyframe] = []
    for k, entry in enumerate(value, 1):
        f = _Table(entry, t.where, f"keyframes #{k} ")
        f.keys(("time", "position", "target"))
        time = f.number("time", _REQUIRED, _NON_NEGATIVE)
        if frames and time <= frames[-1].time:
            raise f.error("time", f"{time:g} s must be after keyframe #{k - 1} ({frames[-1].time:g} s)")
        position, target = f.vector("position", _REQUIRED), f.vector("target", _REQUIRED)
        if target == position:
            raise f.error("target", "must differ from position")
        frames.append(CameraKeyframe(time, position, target))
    return tuple(frames)


def _suggest(word: str, known, show=None) -> str:
    """``; did you mean X?`` for the name in ``known`` closest to ``word``, shown by ``show``; without one
    close enough, `` (expected A, B, ...)`` when ``show`` is given, else nothing."""
    close = difflib.get_close_matches(word, list(known), n=1)
    if close:
        return f"; did you mean {(show or repr)(close[0])}?"
    return f" (expected {', '.join(map(show, known))})" if show else ""


def _table(name: str) -> str:
    return f"[[{name}]]" if TABLES[name] else f"[{name}]"


def _numbers(value, n: int) -> bool:
    """Whether ``value`` is an array of ``n`` numbers (not booleans)."""
    return (
        isinstance(value, list)
        and len(value) == n
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    )


def _a(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def _key(key: str) -> str:
    """A key as a message shows it: bare when TOML allows it bare, else quoted."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else repr(key)


def _shown(value) -> str:
    """A TOML value as a message shows it."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"[{', '.join(map(_shown, value))}]" if len(value) <= 4 else f"an array of {len(value)}"
    return repr(value)
