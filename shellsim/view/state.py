"""What the viewer shows, as plain arrays (no viser): a :class:`ViewState` of bodies, colliders, ground,
cameras and the motion whose frames move the bodies.

A target is one of (:func:`target_kind`): a scene file (``.toml``), a scene's output directory (it holds
``motion.npz`` or the log of a run in progress, ``motion.npz.partial``), a motion file (``.npz``) or an
asset (a shipped name or a directory). :func:`check_target` reads what can be read cheaply (the scene file
by :func:`shellsim.shot.file.read_scene`, an asset's ``asset.json``, a motion's header), so that a wrong
target is one error before anything heavy runs; :func:`load_state` then builds the state.

Each body is displayed as a triangle mesh carried by its cage: an asset body by its outer shell M+ (the
cage's own embedding of it), a mesh body by its surface (its collision surface). A displayed vertex p is
``sum_k bary[p, k] * x[corners[p, k]]`` (paper Sec. 5: barycentric interpolation in the deformed cage),
``x`` the body's share of a motion frame's cage positions (world metres).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neural.errors import InputError

log = logging.getLogger(__name__)

#: Most checker squares along each side of the drawn ground (a finer checker is drawn over a smaller area).
MAX_SQUARES = 160
#: The drawn ground reaches at least this far [m] from the bodies' centre, and 1.5 times their extent.
GROUND_REACH = 1.0
#: (W, H) the cameras' frustums are drawn for (that of the shot's frames, shellsim.film.cameras.VIDEO_SIZE).
FRUSTUM_SIZE = (512, 512)


@dataclass
class BodyView:
    """One displayed body: ``name``; ``vertices`` its slice of a frame's cage vertices; ``rest`` (V_b, 3)
    its rest cage in the world [m]; ``corners`` (P, 4) int, cage vertices (of the body) of each displayed
    vertex's tet, ``bary`` (P, 4) its barycentric coordinates; ``faces`` (F, 3) of the displayed mesh;
    ``color`` (3,) albedo in [0, 1]; ``tets`` (T_b, 4) its cage's tets (into its own vertices);
    ``placement`` (:class:`shellsim.world.Placement`, asset frame -> world); ``colors`` (P, 3) float32
    per-vertex colours (an asset's M+ from its field, :func:`shellsim.film.shell_colors.shell_colors`, times
    its ``tint`` (3,) when it has one) or None; ``asset`` the neural asset or None (a mesh body)."""

    name: str
    vertices: slice
    rest: np.ndarray
    corners: np.ndarray
    bary: np.ndarray
    faces: np.ndarray
    color: tuple
    tets: np.ndarray
    placement: object = None
    colors: np.ndarray | None = None
    asset: object = None
    tint: tuple | None = None

    def displayed(self, positions: np.ndarray) -> np.ndarray:
        """(P, 3) float64 the displayed vertices where the body's cage vertices are ``positions`` (V_b, 3)."""
        x = np.asarray(positions, np.float64)
        out = np.zeros((len(self.corners), 3))
        for k in range(4):
            out += self.bary[:, k, None] * x[self.corners[:, k]]
        return out


@dataclass
class CameraView:
    """A scene camera's pose for its frustum: ``name``, ``c2w`` (4, 4) OpenGL camera-to-world (looks along
    -z, y up) at the shot's first frame, ``fov`` vertical field of view [radians], ``aspect`` W / H."""

    name: str
    c2w: np.ndarray
    fov: float
    aspect: float


@dataclass
class ViewState:
    """Everything shown: ``kind`` of target ("scene", "motion", "asset"); ``scene`` the scene file's path
    (a scene target) and ``spec`` its :class:`~shellsim.shot.spec.SceneSpec`; ``out`` the output directory
    a scene is simulated into; ``motion`` the motion file that moves the bodies (read from its log while a
    run writes it) or None; ``n_motion`` its frames; ``fps``; ``stale`` why the motion is not of the scene
    as the file says it now ("" when it is); ``bodies`` (:class:`BodyView`); ``colliders`` (name,
    vertices (S, 3), faces (F, 3)); ``look`` (:class:`shellsim.world.WorldLook`); ``cameras``
    (:class:`CameraView`); ``n_vertices`` of a frame (every body's cage); ``built`` the bodies as built
    from the scene file (:class:`shellsim.shot.bodies.SceneBody`, a scene or asset target) or
    ``recorded`` the motion's :class:`~shellsim.shot.recorded.SceneMotion` (a scene motion target): what
    the neural picture is made from."""

    kind: str
    bodies: list
    look: object
    fps: float
    n_vertices: int
    colliders: list = field(default_factory=list)
    cameras: list = field(default_factory=list)
    scene: Path | None = None
    spec: object = None
    out: Path | None = None
    motion: Path | None = None
    n_motion: int = 0
    stale: str = ""
    built: list | None = None
    recorded: object = None
    _cached: tuple = (None, None)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def n_frames(self) -> int:
        """Frames shown: the motion's (at least 1: the rest pose when there is none or it is not shown)."""
        return max(self.n_motion, 1) if self.shows_motion else 1

    @property
    def shows_motion(self) -> bool:
        """Whether the motion's frames move the bodies (there is one, with the bodies' layout)."""
        return self.motion is not None and self.n_motion > 0

    @property
    def rest(self) -> np.ndarray:
        """(V, 3) every body's rest cage, one after the other."""
        rest = np.zeros((self.n_vertices, 3))
        for b in self.bodies:
            rest[b.vertices] = b.rest
        return rest

    def positions(self, k: int) -> np.ndarray:
        """(V, 3) the cage positions of shown frame ``k`` (the rest cages without a motion)."""
        k = int(k)
        if not 0 <= k < self.n_frames:
            raise ValueError(f"k: frames 0..{self.n_frames - 1} are shown, got {k}")
        if not self.shows_motion:
            return self.rest
        with self._lock:
            if self._cached[0] == (self.motion, k):
                return self._cached[1]
        from shellsim.motion.read import read_frames

        frame = read_frames(self.motion, [k])[0].astype(np.float64)
        with self._lock:
            self._cached = ((self.motion, k), frame)
        return frame

    def displayed(self, k: int) -> list[np.ndarray]:
        """Each body's displayed vertices (P_b, 3) at shown frame ``k``."""
        positions = self.positions(k)
        return [b.displayed(positions[b.vertices]) for b in self.bodies]

    def refresh(self) -> bool:
        """Read the motion's frame count again (a run may be appending to its log; a run may have started
        one); whether the frames shown changed. A scene target's motion is compared with the scene file
        (:func:`stale_reason`); one whose cages are not the bodies' is not shown (said in ``stale``)."""
        from shellsim.motion.read import read_motion_info

        if self.motion is None:
            return False
        try:
            info = read_motion_info(self.motion)
        except InputError:  # not there yet, or damaged: the previous frames stay shown
            return False
        n = info.n_frames
        if self.kind == "scene":
            self.stale = stale_reason(self.spec, info)
            if not _same_layout(self, info):
                n = 0
                self.stale = (self.stale or "made from other bodies") + "; its frames are not shown"
        changed = n != self.n_motion
        self.n_motion = n
        if changed:
            with self._lock:
                self._cached = (None, None)
        return changed

    def compute_colors(self, device: str = "cpu") -> None:
        """Fill each asset body's ``colors`` from its field (once per asset); an asset whose field cannot
        be loaded keeps its albedo, said in the log."""
        from neural.asset import load_field
        from neural.device import pick_device
        from shellsim.film.shell_colors import shell_colors

        device = pick_device(device)
        done = {}
        for b in self.bodies:
            if b.asset is None or b.colors is not None:
                continue
            key = str(Path(b.asset.root).resolve())
            if key not in done:
                try:
                    done[key] = shell_colors(b.asset, load_field(b.asset, device), device)
                except InputError as err:
                    log.warning("%s: shown in one colour: %s", b.name, err)
                    done[key] = None
            b.colors = done[key]
            if b.colors is not None and b.tint is not None:
                b.colors = (b.colors * np.asarray(b.tint, np.float32)).astype(np.float32)

    def ground(self):
        """The ground checker as two meshes ``((vertices, faces), (vertices, faces))``, one per colour of
        the look, squares of ``look.square`` metres about the bodies' centre; None without a ground."""
        if not self.look.ground:
            return None
        points = [self.rest] + [v for _, v, _ in self.colliders]
        points = np.concatenate([p.reshape(-1, 3) for p in points])
        lo, hi = points.min(0), points.max(0)
        centre = 0.5 * (lo + hi)
        reach = max(GROUND_REACH, 1.5 * float(np.max(hi[:2] - lo[:2])))
        return checker_meshes(centre[:2], reach, self.look.square)


def checker_meshes(centre, reach: float, square: float):
    """Two meshes ``(vertices (4n, 3), faces (2n, 3))`` of the squares of side ``square`` at z = 0 with
    ``(i + j)`` even and odd (``i, j`` the squares' indices from the world origin), covering the square
    ``centre +- reach`` (at most :data:`MAX_SQUARES` squares a side, about the centre)."""
    n = min(MAX_SQUARES, int(np.ceil(2 * reach / square)))
    first = np.floor(np.asarray(centre, np.float64) / square).astype(np.int64) - n // 2
    i, j = np.meshgrid(np.arange(n) + first[0], np.arange(n) + first[1], indexing="ij")
    i, j = i.ravel(), j.ravel()
    out = []
    for parity in (0, 1):
        mine = (i + j) % 2 == parity
        x0, y0 = i[mine] * square, j[mine] * square
        corners = np.stack(
            [
                np.stack([x0, y0], 1),
                np.stack([x0 + square, y0], 1),
                np.stack([x0 + square, y0 + square], 1),
                np.stack([x0, y0 + square], 1),
            ],
            1,
        )  # (n, 4, 2)
        vertices = np.concatenate([corners, np.zeros(corners.shape[:2] + (1,))], 2).reshape(-1, 3)
        base = 4 * np.arange(len(x0))[:, None]
        faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.int64)
        out.append((vertices, faces))
    return tuple(out)


def target_kind(target) -> str:
    """ "scene" (a ``.toml``), "motion" (a ``.npz``, or a directory holding ``motion.npz`` or its log),
    "asset" (a directory with ``asset.json``, or the name of a shipped asset); an :class:`InputError` naming
    ``target`` when it is none of them."""
    from shellsim.motion.writer import motion_exists

    path = Path(target)
    if path.suffix == ".toml":
        return "scene"
    if path.suffix == ".npz":
        if not motion_exists(path):
            raise InputError(f"{target}: motion file not found")
        return "motion"
    if path.is_dir():
        if motion_exists(path / "motion.npz"):
            return "motion"
        if (path / "asset.json").is_file():
            return "asset"
        raise InputError(
            f"{target}: neither a scene's output directory (motion.npz) nor an asset (asset.json)"
        )
    if path.exists():
        raise InputError(f"{target}: not a scene file (.toml), a motion file (.npz) or a directory")
    if len(path.parts) == 1:
        return "asset"  # a shipped asset's name; load_asset names those there are
    raise InputError(f"{target}: no such file or directory")


def check_target(target):
    """``(kind, what)`` of ``target`` (:func:`target_kind`) after the cheap checks: ``what`` is the scene
    file's :class:`SceneSpec`, the asset or the motion's :class:`MotionInfo`. Every problem is one
    :class:`InputError` (a scene file's: :class:`~shellsim.shot.spec.SceneError`, ``FILE: [table] key:
    problem``)."""
    kind = target_kind(target)
    if kind == "scene":
        from shellsim.shot.file import read_scene

        return kind, read_scene(target)
    if kind == "asset":
        from neural.asset import load_asset

        return kind, load_asset(target)
    from shellsim.motion.read import read_motion_info
    from shellsim.shot.recorded import motion_path

    return kind, read_motion_info(motion_path(target))


def load_state(target, out=None, colors: bool = False, device: str = "auto") -> ViewState:
    """The :class:`ViewState` of ``target`` (module docstring); ``out`` the output directory of a scene
    target (None: the scene job's default, the file without ``.toml``); ``colors``: compute the asset
    bodies' M+ colours now (:meth:`ViewState.compute_colors`)."""
    kind, what = check_target(target)
    if kind == "scene":
        state = scene_state(what, out)
    elif kind == "asset":
        state = asset_state(what)
    else:
        state = motion_state(target)
    if colors:
        state.compute_colors(device)
    return state


def _built_bodies(spec):
    """Every body of ``spec`` built (:func:`shellsim.shot.bodies.build_body`: cages and collision surfaces
    loaded or built, cached) and placed, as the scene job places them: ``(views, bodies, n_vertices)``,
    their :class:`BodyView` and :class:`~shellsim.shot.bodies.SceneBody`."""
    from shellsim.shot.bodies import build_body, lowest_start
    from shellsim.shot.recorded import MESH_BODY_COLORS, body_color

    lift = lowest_start(spec.world)
    views, built, start = [], [], 0
    for k, body_spec in enumerate(spec.bodies):
        body = build_body(body_spec, lift)
        built.append(body)
        n = len(body.rest)
        if body_spec.asset is not None:
            cage, asset = body.cage, _asset_of(body_spec.asset)
            corners, bary = np.asarray(cage.tets)[cage.outer_tet], cage.outer_bary
            faces = np.asarray(asset.outer_mesh().faces, np.int64)
        else:
            asset, s = None, body.surface
            corners, bary, faces = s.corners, s.bary, np.asarray(s.faces, np.int64)
        color = body_color(body_spec.color, k, asset is None)
        views.append(
            BodyView(
                body.name,
                slice(start, start + n),
                body.rest,
                np.asarray(corners, np.int64),
                np.asarray(bary, np.float64),
                faces,
                color or MESH_BODY_COLORS[k % len(MESH_BODY_COLORS)],
                body.tets,
                body.placement,
                asset=asset,
                tint=None if asset is None else color,
            )
        )
        start += n
    return views, built, start


def _asset_of(name):
    from neural.asset import load_asset

    return load_asset(name)


def _look(spec, ground: bool):
    from shellsim.film.world import look_of

    return look_of(spec, ground)


def scene_state(spec, out=None) -> ViewState:
    """A scene file's :class:`ViewState`: its bodies built and placed, its colliders, cameras and look, and
    the motion in its output directory ``out`` when there is one (marked stale when the file changed
    since)."""
    from shellsim.jobs.scene import SceneSettings
    from shellsim.motion.writer import motion_exists
    from shellsim.shot.bodies import collider_mesh

    bodies, built, n = _built_bodies(spec)
    out = Path(out) if out is not None else SceneSettings(scene=spec.path).out_dir
    colliders = [(c.name, *collider_mesh(c)) for c in spec.colliders]
    state = ViewState(
        "scene",
        bodies,
        _look(spec.look, spec.world.ground),
        spec.world.fps,
        n,
        colliders,
        scene=Path(spec.path),
        spec=spec,
        out=out,
        motion=out / "motion.npz",
        built=built,
    )
    scene = None
    if motion_exists(state.motion):
        state.refresh()
        if state.shows_motion and not state.stale:
            from shellsim.shot.recorded import read_scene_motion

            scene = read_scene_motion(state.motion, load_assets=False)
    state.cameras = camera_views(state, list(spec.cameras), scene)
    return state


def asset_state(asset) -> ViewState:
    """An asset alone on the ground, placed as ``shellsim simulate`` places it (its one-body shot,
    :func:`shellsim.jobs.simulate.scene_of`); no motion."""
    from shellsim.jobs.simulate import SimulateSettings, scene_of

    where = str(asset.root) if not _is_shipped(asset) else asset.name
    spec = scene_of(SimulateSettings(asset=where))
    bodies, built, n = _built_bodies(spec)
    look = _look(spec.look, spec.world.ground)
    return ViewState("asset", bodies, look, spec.world.fps, n, spec=spec, built=built)


def _is_shipped(asset) -> bool:
    from neural.asset import shipped_assets_dir

    return Path(asset.root).resolve().parent == shipped_assets_dir().resolve()


def motion_state(target) -> ViewState:
    """A motion file's :class:`ViewState`: a scene motion's bodies (:mod:`shellsim.shot.recorded`), else one
    body shown by the motion's surface (or its cage's boundary)."""
    from shellsim.motion.read import read_motion_info
    from shellsim.shot.recorded import MESH_BODY_COLORS, is_scene_motion, motion_path, read_scene_motion
    from shellsim.world import WorldLook

    path = motion_path(target)
    info = read_motion_info(path)
    fps = _fps(info)
    if not is_scene_motion(info):
        body = _plain_body(info)
        state = ViewState("motion", [body], WorldLook(), fps, len(info.rest_vertices), motion=path)
        state.refresh()
        return state
    scene = read_scene_motion(path)
    bodies = []
    for k, (b, record) in enumerate(zip(scene.bodies, info.asset["bodies"], strict=True)):
        rest = np.asarray(info.rest_vertices[b.vertices], np.float64)
        t_lo, t_hi = record["tets"]
        tets = np.asarray(info.tets[t_lo:t_hi], np.int64) - b.vertices.start
        if b.asset is not None:
            cage = b.cage
            corners, bary = np.asarray(cage.tets)[cage.outer_tet], cage.outer_bary
            faces = np.asarray(b.asset.outer_mesh().faces, np.int64)
        else:
            corners, bary, faces = b.surface_corners, b.surface_bary, b.surface_faces
        bodies.append(
            BodyView(
                b.name,
                b.vertices,
                rest,
                corners,
                bary,
                faces,
                b.color or MESH_BODY_COLORS[k % len(MESH_BODY_COLORS)],
                tets,
                b.placement,
                asset=b.asset,
                tint=None if b.asset is None else b.color,
            )
        )
    colliders = []
    if scene.colliders:
        from shellsim.shot.bodies import collider_mesh

        colliders = [(c.name, *collider_mesh(c)) for c in scene.colliders]
    state = ViewState(
        "motion", bodies, _look(scene.look, scene.ground), fps, len(info.rest_vertices), colliders
    )
    state.motion, state.recorded = path, scene
    state.refresh()
    state.cameras = camera_views(state, list(scene.cameras), scene)
    return state


def _fps(info) -> float:
    times = np.asarray(info.times, np.float64)
    world = info.settings.get("world", {}) if isinstance(info.settings, dict) else {}
    if "fps" in world:
        return float(world["fps"])
    if "fps" in info.settings:
        return float(info.settings["fps"])
    return float(1.0 / np.median(np.diff(times))) if len(times) > 1 else 30.0


def _plain_body(info) -> BodyView:
    """The one body of a motion that is not a scene's: its surface carried by the cage when it has one,
    else the cage's boundary faces."""
    from shellsim.tetcage.geometry import boundary_faces

    rest = np.asarray(info.rest_vertices, np.float64)
    tets = np.asarray(info.tets, np.int64)
    if info.surface is not None:
        s = info.surface
        corners, bary, faces = tets[s.tet], np.asarray(s.bary, np.float64), np.asarray(s.faces, np.int64)
    else:
        faces = boundary_faces(tets)
        used, local = np.unique(faces, return_inverse=True)
        corners = np.repeat(used[:, None], 4, 1)
        bary = np.tile([1.0, 0.0, 0.0, 0.0], (len(used), 1))
        faces = local.reshape(-1, 3)
    name = str(info.asset.get("name", "body")) if isinstance(info.asset, dict) else "body"
    return BodyView(name, slice(0, len(rest)), rest, corners, bary, faces, (0.25, 0.50, 0.80), tets)


def stale_reason(spec, info) -> str:
    """Why the motion ``info`` is not of the scene ``spec`` as its file says it now ("" when it is): the
    settings that changed, compared as the scene job compares them (all but the cameras and the look of
    :func:`shellsim.jobs.scene.scene_record`), or another producer."""
    from shellsim.jobs.scene import PRODUCER, scene_record, simulated_part
    from shellsim.motion.changes import describe_changes

    if info.producer != PRODUCER:
        return f"{info.path}: not a scene motion (made by '{info.producer}')"

    def simulated(record: dict) -> dict:
        return {k: _keyed(v) for k, v in simulated_part(record).items()}

    changes = describe_changes(simulated(info.settings), simulated(scene_record(spec)))
    if not changes:
        return ""
    return (
        "made from another version of the scene ("
        + "; ".join(c.replace("{", "").replace("}", "") for c in changes)
        + ")"
    )


def _keyed(value):
    """A table's list of entries (bodies, colliders, actions) as a dict by name (else by position), so that
    a change is named by its key ("material: rubber -> jelly"), not as the whole list."""
    if isinstance(value, list | tuple) and value and all(isinstance(v, dict) for v in value):
        return {str(v.get("name") or k): v for k, v in enumerate(value)}
    return value


def _same_layout(state: ViewState, info) -> bool:
    """Whether the motion ``info`` moves cages of the state's bodies' sizes, in their order."""
    records = info.asset.get("bodies", []) if isinstance(info.asset, dict) else []
    if len(info.rest_vertices) != state.n_vertices or len(records) != len(state.bodies):
        return False
    return all(
        list(r["vertices"]) == [b.vertices.start, b.vertices.stop]
        for r, b in zip(records, state.bodies, strict=True)
    )


def camera_views(state: ViewState, cameras: list, scene=None) -> list[CameraView]:
    """The first frame's pose of each scene camera (:func:`shellsim.film.cameras.scene_shot`), framed to
    the motion's bodies (``scene``: a :class:`~shellsim.shot.recorded.SceneMotion`, over its frames) or,
    without one, to the bodies at rest held over the shot's frames."""
    from shellsim.film.cameras import scene_shot

    if not cameras:
        return []
    tracks = _tracks(state, scene if state.shows_motion else None)
    width, height = FRUSTUM_SIZE
    placements = _placements(state, scene)
    views = []
    for spec in cameras:
        try:
            shot = scene_shot(spec, tracks, width, height, placements)
        except (InputError, ValueError) as err:
            log.warning("camera %s: not drawn (%s)", spec.name, err)
            continue
        fov = 2.0 * np.arctan(0.5 * height / shot.focal)
        views.append(CameraView(spec.name, np.asarray(shot.c2w[0], np.float64), float(fov), width / height))
    return views


def _tracks(state: ViewState, scene):
    """Each body's :class:`~shellsim.film.cameras.MotionTrack` by name and all of them under "": over the
    motion of ``scene`` (a :class:`~shellsim.shot.recorded.SceneMotion`), else the bodies at rest held
    over the shot's frames."""
    from shellsim.film.cameras import MotionTrack, mass_weights

    if scene is not None:
        from shellsim.film.shot_frames import scene_tracks

        return scene_tracks(scene)
    frames = state.spec.world.frames if state.spec is not None else 1
    times = np.arange(frames) / state.fps
    weights = np.zeros(state.n_vertices)
    for b in state.bodies:
        weights[b.vertices] = mass_weights(b.rest, b.tets)
    rest = state.rest
    parts = [(b.name, b.vertices) for b in state.bodies] + [("", slice(0, len(rest)))]
    tracks = {}
    for name, share in parts:
        mine, w = rest[share], weights[share] / weights[share].sum()
        lo, hi, centre = mine.min(0), mine.max(0), w @ mine
        tracks[name] = MotionTrack(*(np.tile(a, (frames, 1)) for a in (lo, hi, centre)), times)
    return tracks


def _placements(state: ViewState, scene):
    if scene is not None:
        return {b.name: b.placement for b in scene.bodies}
    return {b.name: b.placement for b in state.bodies}
