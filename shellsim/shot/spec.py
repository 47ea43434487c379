"""What a scene file says, once read and checked (:mod:`shellsim.shot.file`): plain frozen dataclasses in SI
units (metres, seconds, kg/m^3, Pa, radians per second, degrees for rotations), z up, the ground at z = 0.

Nothing here loads an asset or a mesh: :class:`SceneSpec` is what a user wrote, with defaults filled in and
every value in its domain. Where a value came from (``FILE: [table] key``) is kept in each part's
``where`` so a later check (a region that selects nothing, two bodies overlapping) names it the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from neural.errors import InputError
from shellsim.physics.ipc import CONTACT_GAP, FRICTION_VELOCITY
from shellsim.world import WorldLook

Vec3 = tuple[float, float, float]
RGB = tuple[float, float, float]  # each in [0, 1]
_LOOK = WorldLook()


class SceneError(InputError):
    """A scene file is wrong: one line ``FILE: [table] key: problem``."""


@dataclass(frozen=True)
class WorldSpec:
    """``[world]``: the clock, gravity, the ground and the contact model shared by every body."""

    fps: float = 30.0  # frames per second
    frames: int = 60  # frames of the shot (``duration * fps`` rounded, when the file gives a duration)
    substeps: int = 8  # implicit steps per frame
    gravity: float = 9.81  # [m/s^2] along -z; 0 for none
    ground: bool = True  # the plane z = 0
    ground_friction: float = 0.5  # Coulomb coefficient between the ground and a body
    damping: float = 0.0  # Kelvin-Voigt beta [s], for bodies that set none
    drag: float = 0.0  # velocity drag [1/s]
    contact_gap: float = CONTACT_GAP  # the barrier's activation distance dhat [m]
    friction_velocity: float = FRICTION_VELOCITY  # sliding speed below which friction is smoothed [m/s]
    settle: float = 0.0  # [s] simulated before frame 0 with gravity, contact and pins only, strongly damped
    integrator: str = (
        "euler"  # "euler" (backward Euler) or "bdf2" (second order: livelier, less numerical damping)
    )

    @property
    def duration(self) -> float:
        return self.frames / self.fps


@dataclass(frozen=True)
class CageSpec:
    """``[body.cage]``: overrides of :class:`shellsim.tetcage.build.CageConfig` (None: its default)."""

    target_tets: int | None = None
    margin: float | None = None


@dataclass(frozen=True)
class BodySpec:
    """One ``[[body]]``: an asset (a shipped name or a directory) or a closed triangle mesh, placed in the
    world.

    The body is turned so the asset's up axis (``up``, else the asset's own) is +z (a mesh is taken as z
    up), scaled so its largest extent is ``size`` metres (a mesh without ``size`` keeps its own size in
    ``units``), rotated by ``rotation``
    (degrees about the world x, y, then z axes, through its bounding-box centre), and moved so the bottom
    centre of its bounding box is at ``position``. ``material`` is a preset of
    :mod:`shellsim.physics.materials`; ``youngs`` [Pa], ``poisson``, ``density`` [kg/m^3] override it.
    ``velocity`` [m/s] and ``spin`` [rad/s, about the centre of mass] start it moving. ``color`` is a mesh
    body's albedo (None: :data:`shellsim.shot.recorded.MESH_BODY_COLORS`) and an asset body's tint, which
    multiplies its field's colours (None: none).
    """

    name: str
    asset: str | None = None  # resolved path of an asset directory, or a shipped asset's name
    mesh: str | None = None  # resolved path of a closed triangle mesh
    units: str = "m"  # a mesh's units: m, cm, mm, in, ft
    size: float | None = None  # [m] largest extent; None: the asset default (0.3 m), a mesh's own size
    position: Vec3 = (0.0, 0.0, 0.0)  # [m] bottom centre of the placed bounding box
    rotation: Vec3 = (0.0, 0.0, 0.0)  # [degrees] about world x, then y, then z
    material: str = "rubber"
    youngs: float | None = None
    poisson: float | None = None
    density: float | None = None
    damping: float | None = None  # Kelvin-Voigt beta [s]; None: the world's
    friction: float = 0.5  # Coulomb coefficient of this body's surface
    velocity: Vec3 = (0.0, 0.0, 0.0)
    spin: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 | None = None  # an asset's up axis in its own frame; None: the asset's
    color: RGB | None = None  # a mesh's albedo, an asset's tint; None: the palette's, no tint
    cage: CageSpec = field(default_factory=CageSpec)
    where: str = ""  # "FILE: [[body]] #k (NAME)"


@dataclass(frozen=True)
class ColliderSpec:
    """One ``[[collider]]``: a static box, sphere or closed triangle mesh (``shape``).

    box: ``half_extents`` [m]; sphere: ``radius`` [m]; mesh: ``mesh`` (resolved path), ``units`` and ``scale``
    (a factor on top of the units). Each is rotated by ``rotation`` (degrees about world x, y, z through its
    centre) and its centre put at ``position`` [m] (a mesh's centre is its bounding-box centre). ``color``:
    its albedo (None: the look's ``collider_color``).
    """

    name: str
    shape: str  # "box", "sphere" or "mesh"
    position: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)
    half_extents: Vec3 | None = None
    radius: float | None = None
    mesh: str | None = None
    units: str = "m"
    scale: float = 1.0
    friction: float = 0.5
    color: RGB | None = None
    where: str = ""


@dataclass(frozen=True)
class Keyframe:
    """A grab's pose at ``time`` [s]: the region moved by ``position`` [m] and turned by ``rotation``
    [degrees about world x, y, z, through the region's centre] from where it was when the grab began."""

    time: float
    position: Vec3 = (0.0, 0.0, 0.0)
    rotation: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ActionSpec:
    """One ``[[action]]``, active for ``start <= t < end`` [s].

    - ``pin``: the vertices of ``region`` held where they are at ``start``, released at ``end``;
    - ``grab``: the region moved rigidly along ``keyframes`` (linear in position, spherical in rotation,
      held at the last keyframe after it), released at ``end``;
    - ``push``: the region's velocity changed by ``velocity`` [m/s] spread evenly over the window (a force
      ``m_i dv / (end - start)`` on each of its vertices), or a total ``force`` [N] shared by mass; with
      ``end == start`` a ``velocity`` push is an impulse at ``start``;
    - ``wind``: air moving at ``speed`` [m/s] along ``direction`` (horizontal), with the gusts and travelling
      turbulence of :mod:`shellsim.physics.wind`, dragging the bodies' surfaces (``drag_coefficient``,
      air density 1.2 kg/m^3); on ``body`` or, when it is None, on every body.

    ``region`` is a list of rules of :mod:`shellsim.physics.selection`, applied to the body's cage vertices
    where the body is at t = 0 (percentages relative to its bounding box then); every rule must hold
    (empty: the whole body).
    """

    kind: str  # "pin", "grab", "push", "wind"
    start: float
    end: float
    body: str | None = None  # the body's name; None only for wind (every body)
    region: tuple[str, ...] = ()
    keyframes: tuple[Keyframe, ...] = ()
    velocity: Vec3 | None = None
    force: Vec3 | None = None
    speed: float = 0.0
    direction: Vec3 = (1.0, 0.0, 0.0)
    gust: float = 0.3
    gust_frequency: float = 1.0  # [Hz]
    turbulence: float = 0.3
    drag_coefficient: float = 1.0
    where: str = ""


@dataclass(frozen=True)
class CameraKeyframe:
    """Where a ``path`` camera is at ``time`` [s]: at ``position`` [m] looking at ``target`` [m]."""

    time: float
    position: Vec3
    target: Vec3


@dataclass(frozen=True)
class CameraSpec:
    """One ``[[camera]]``: how a shot is framed (its frames: :func:`shellsim.film.cameras.scene_shot`).

    ``kind``:

    - ``orbit``: around ``target`` at ``distance`` [m] and ``elevation`` [degrees], its azimuth [degrees
      about z from +x towards +y] going from ``azimuth - degrees / 2`` to ``azimuth + degrees / 2`` over the
      shot;
    - ``fixed``: at ``position`` looking at ``target``;
    - ``follow``: keeps the offset ``position - target`` (``target`` None: the centre of mass of ``body`` at
      t = 0) from the smoothed centre of mass of the body ``body``, looking at it;
    - ``path``: along ``keyframes`` (at least 2, times increasing), its position and target interpolated
      by a Catmull-Rom spline through them, held before the first and after the last;
    - ``front``, ``side``, ``top``, ``three-quarter``: the presets of :data:`shellsim.world.CAMERA_PRESETS`,
      still, keeping every body over the whole shot in view (three-quarter at ``elevation``);
    - ``capture``: along the cameras of the camera file ``path`` (a ``transforms*.json`` or a dataset
      directory, in the asset's frame of the asset body ``body``) once over the shot, in the file's order,
      their path smoothed over ``smooth`` views (0: the file's own cameras).

    ``fov`` [degrees] horizontal (as :mod:`shellsim.film.cameras`; None, capture only: the file's own);
    ``target`` None (orbit, fixed): the centre of the bodies' box at t = 0; ``distance`` None: the least
    that keeps every body in view.
    """

    name: str
    kind: str = "orbit"
    position: Vec3 | None = None
    target: Vec3 | None = None
    distance: float | None = None  # None: framed to the bodies
    elevation: float = 20.0
    azimuth: float = 30.0
    degrees: float = 30.0
    fov: float | None = 40.0
    body: str | None = None
    keyframes: tuple[CameraKeyframe, ...] = ()
    path: str | None = None  # resolved path of a capture's camera file
    smooth: float = 2.0  # [views] standard deviation of a capture's Gaussian smoothing
    where: str = ""


@dataclass(frozen=True)
class LookSpec:
    """``[look]``: how the shot's frames look (:func:`shellsim.film.world.look_of`); the defaults are those
    of :class:`shellsim.world.WorldLook`."""

    ground_colors: tuple[RGB, RGB] = _LOOK.ground_colors  # the ground checker's two colours
    square: float = _LOOK.square  # [m] side of the checker's squares
    light: Vec3 = _LOOK.light  # direction toward the light (any length, not zero)
    ambient: float = _LOOK.ambient  # the sky's share of a lit point's brightness
    diffuse: float = _LOOK.diffuse  # the light's share
    shadows: bool = _LOOK.shadows
    sky: tuple[RGB, ...] = (_LOOK.zenith, _LOOK.horizon)  # one colour (plain) or the zenith's and horizon's
    collider_color: RGB = _LOOK.obstacle_color  # the static colliders' albedo


@dataclass(frozen=True)
class SceneSpec:
    """A whole scene file: ``path`` (resolved), the world, the bodies (at least one), the static colliders,
    the timed actions, the cameras and the look of its frames."""

    path: str
    world: WorldSpec
    bodies: tuple[BodySpec, ...]
    colliders: tuple[ColliderSpec, ...] = ()
    actions: tuple[ActionSpec, ...] = ()
    cameras: tuple[CameraSpec, ...] = ()
    look: LookSpec = field(default_factory=LookSpec)

    def body(self, name: str) -> BodySpec:
        return next(b for b in self.bodies if b.name == name)
