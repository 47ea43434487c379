"""The browser viewer (viser): a shot's bodies, colliders, ground and cameras at once, a timeline over its
motion, the neural picture of the current view, and "Simulate in place".

:class:`Viewer` is a library object (tests and notebooks drive it; ``shellsim view`` is its command line):
``Viewer(host, port, device)``, :meth:`Viewer.open` a target (:mod:`shellsim.view.state`),
:meth:`Viewer.frame` to show a motion frame, :attr:`Viewer.n_frames`, :attr:`Viewer.url`,
:meth:`Viewer.close`. What is shown is kept in a :class:`~shellsim.view.state.ViewState` (plain arrays);
this module only draws it and runs the page's controls. The server starts once a target has loaded, so a
wrong target starts nothing.

The page (every client sees the same scene and controls):

- the ground as a checker of the look's square size and colours, the colliders, every body as a mesh (an
  asset body by its outer shell M+ in the colours its field gives it, computed in the background; a mesh
  body by its surface in its albedo), the scene file's cameras as frustums at the shot's first frame;
- a timeline over the motion's frames with Play / Pause at the shot's fps;
- for a scene file, "Simulate": the scene job in a worker process (:mod:`shellsim.view.worker`), its frames
  added to the timeline as they are written; its error shown on the page. A motion made from another
  version of the scene is marked stale;
- the neural picture (:class:`shellsim.view.picture.NeuralPicture`) of each client's view as the page's
  background, with its depth so that meshes in front of it stay visible, and "Meshes only" to turn it off;
  only where every asset body's field loads;
- "Live" (:class:`shellsim.view.live.LiveShot`, :meth:`Viewer.start_live`): the shot stepping on coarse
  cages; a click on a body (:meth:`Viewer.pick`) starts a poke whose target follows transform-control arrows,
  the spring drawn as a line; a released poke can be recorded as a ``push``;
- for a scene file, "Camera from this view" and "Save the scene file"
  (:class:`shellsim.view.edit.SceneEditor`: the only file the page writes).
"""

from __future__ import annotations

import contextlib
import io
import logging
import threading
import time

import numpy as np

from neural.errors import ShellsimError

log = logging.getLogger(__name__)

#: Seconds between two looks at the motion's log while a run may be writing it.
POLL_SECONDS = 0.5
#: Hosts that only this machine reaches.
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
MISSING_VISER = 'shellsim view needs viser: pip install -e ".[view]"'


def import_viser():
    """The ``viser`` module, or a :class:`ShellsimError` saying how to install it."""
    try:
        import viser
    except ImportError:
        raise ShellsimError(MISSING_VISER) from None
    return viser


def _rgb(color) -> tuple[int, int, int]:
    return tuple(int(round(255 * float(c))) for c in color)


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    import viser.transforms as tf

    return tf.SO3.from_matrix(np.asarray(rotation, np.float64)).wxyz


class Viewer:
    """A shot in the browser (module docstring).

    host, port : where the page is served (port 0: any free port; a port in use: the next free one, as
        viser does); device : of the neural picture, the colours and the simulation (auto, cpu, cuda);
    colors : compute the asset bodies' M+ colours from their fields (in the background);
    picture : render the neural picture where the bodies' fields load (in the background).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8080,
        device: str = "auto",
        colors: bool = True,
        picture: bool = True,
    ):
        self.host, self.port, self.device = host, int(port), device
        self.colors, self.use_picture = colors, picture
        self.server = None
        self.state = None
        self.picture = None
        self.simulation = None
        self.live = None
        self._lock = threading.RLock()
        self._frame = 0
        self._meshes_only = False
        self._handles: dict[str, object] = {}
        self._gui: dict[str, object] = {}
        self._stop = threading.Event()
        self._playing = threading.Event()
        self._threads: list[threading.Thread] = []
        self._generation = 0
        self._picture_generation = 0
        self._shown_picture = False
        self._sent: dict[str, np.ndarray] = {}
        self._faces: dict[str, np.ndarray] = {}  # live mode's display faces, where they differ
        self._editor = None
        self._moved: dict[str, tuple] = {}  # positions given by "Move" since the file was opened
        self._reported = None

    # -- the library API ---------------------------------------------------------------------------------

    def open(self, target, out=None) -> Viewer:
        """Load ``target`` (a scene file, a scene's output directory, a motion file or an asset; module
        :mod:`shellsim.view.state`) and show it; ``out``: a scene's output directory (None: the scene job's
        default). Starts the server on the first call. A wrong target is a :class:`ShellsimError` and
        leaves the viewer as it was."""
        from shellsim.view.state import load_state

        import_viser()
        state = load_state(target, out)
        self._start_server()
        with self._lock:
            self.live = None
            self._end_background()
            self.state, self._frame, self._reported = state, 0, None
            self.server.scene.reset()
            self.server.gui.reset()
            self._handles, self._gui, self._sent = {}, {}, {}
            self._shown_picture = False
            self._draw_world()
            self._draw_bodies(self.state.displayed(0))
            self._build_gui()
        self._background(self._poll, "poll")
        self._background(self._player, "play")
        if self.colors and any(b.asset is not None for b in state.bodies):
            self._background(self._compute_colors, "colors")
        if self.use_picture and any(b.asset is not None for b in state.bodies):
            self._background(self._build_picture, "picture")
        return self

    @property
    def url(self) -> str:
        """The page's address."""
        if self.server is None:
            raise RuntimeError("url: the viewer has not opened a target yet")
        host = self.host if self.host not in ("0.0.0.0", "::", "") else "127.0.0.1"
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.server.get_port()}"

    @property
    def n_frames(self) -> int:
        """Frames of the timeline (the motion's, else 1: the bodies at rest)."""
        return 0 if self.state is None else self.state.n_frames

    @property
    def current_frame(self) -> int:
        return self._frame

    def frame(self, k: int) -> None:
        """Show motion frame ``k``: every body's mesh moved with its cage (barycentric interpolation of the
        frame's cage positions), the timeline set to ``k``, the neural picture asked for anew."""
        if self.state is None:
            raise RuntimeError("frame: the viewer has not opened a target yet")
        k = int(k)
        n = self.state.n_frames
        if not 0 <= k < n:
            raise ValueError(f"k: the timeline has frames 0..{n - 1}, got {k}")
        with self._lock:
            self._frame = k
            if self.live is None:  # live, the bodies are where the live shot has them
                self._draw_bodies(self.state.displayed(k))
            slider = self._gui.get("frame")
            if slider is not None and slider.value != k:
                slider.value = k
        self._ask_pictures()

    def displayed(self, body: str) -> np.ndarray:
        """(P, 3) float32 the vertices of ``body``'s mesh as sent to the page."""
        return self._sent[body]

    def play(self, on: bool = True) -> None:
        """Play (or pause) the timeline at the shot's fps, from the frame shown, looping."""
        (self._playing.set if on else self._playing.clear)()
        button = self._gui.get("play")
        if button is not None:
            button.label = "Pause" if on else "Play"

    def simulate(self, overwrite: bool = False):
        """Run the scene job on the scene file into its output directory in a worker process
        (:class:`shellsim.view.worker.Simulation`; ``overwrite``: start a motion of another scene anew, as
        ``shellsim scene`` with ``overwrite`` does); its frames join the timeline as they are written."""
        from shellsim.jobs.scene import SceneSettings
        from shellsim.view.worker import Simulation

        state = self.state
        if state is None or state.kind != "scene":
            raise RuntimeError("simulate: only a scene file can be simulated in place")
        with self._lock:
            if self.simulation is not None and self.simulation.running:
                raise RuntimeError("simulate: a simulation is already running")
            settings = SceneSettings(
                scene=str(state.scene), out=str(state.out), overwrite=overwrite, device=self.device
            )
            self.simulation, self._reported = Simulation(settings), None
            if overwrite:
                state.n_motion = 0
                state.stale = ""
        self._status()
        return self.simulation

    def start_live(self, **settings) -> None:
        """Live mode: the scene (a scene file or an asset) stepping continuously on coarse cages
        (:class:`shellsim.view.live.LiveShot`, ``settings`` its keyword arguments), drawn as it moves;
        :meth:`poke` pulls a body. The timeline shows the live shot until :meth:`stop_live`."""
        from shellsim.view.live import LiveShot

        state = self.state
        if state is None or state.spec is None or state.kind not in ("scene", "asset"):
            raise RuntimeError("start_live: only a scene file or an asset moves live")
        if self.live is not None:
            return
        from shellsim.settings import device_setting

        self.play(False)
        self.live = LiveShot(state.spec, device=device_setting(self.device, warp=True), **settings)
        self._background(self._run_live, "live")

    def stop_live(self) -> None:
        """Back from live mode to the motion's frame shown."""
        live, self.live = self.live, None
        if live is not None:
            live.release()
            with self._lock:
                self._faces = {}
                self._handles = {k: v for k, v in self._handles.items() if not k.startswith("/bodies/")}
                for body in self.state.bodies:
                    self.server.scene.remove_by_name(f"/bodies/{body.name}")
            self.frame(self._frame)

    def poke(self, body, point, target) -> None:
        """Pull ``body`` (a name or an index) at the world ``point`` (3,) [m] on its surface toward
        ``target`` (3,) [m] (:meth:`shellsim.view.live.LiveShot.poke`: a spring with capped force); live
        mode only."""
        if self.live is None:
            raise RuntimeError("poke: live mode is off (start_live)")
        self.live.poke(body, point, target)

    def release(self):
        """End the poke held; its :class:`shellsim.view.live.PokeRecord` (None without one)."""
        return None if self.live is None else self.live.release()

    def pick(self, origin, direction) -> tuple[str, np.ndarray] | None:
        """(body name, the world point (3,)) where the ray ``origin + t direction`` first meets a body's
        displayed mesh, or None."""
        import trimesh

        origin = np.asarray(origin, np.float64).reshape(1, 3)
        direction = np.asarray(direction, np.float64).reshape(1, 3)
        best = None
        for body in self.state.bodies:
            vertices = self._sent.get(body.name)
            faces = self._faces.get(body.name, body.faces)
            if vertices is None or len(faces) == 0:
                continue
            mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), faces, process=False)
            hits, _, _ = mesh.ray.intersects_location(origin, direction, multiple_hits=False)
            for hit in hits:
                distance = float(np.dot(hit - origin[0], direction[0]))
                if distance > 0 and (best is None or distance < best[0]):
                    best = (distance, body.name, hit)
        return None if best is None else (best[1], best[2])

    @staticmethod
    def _from_page(what: str, handler):
        """``handler`` of a page's message (``what``), made safe: whatever it raises drops the message with
        one log line, and the server keeps running (a page may be malformed or hostile)."""

        def guarded(*args):
            try:
                return handler(*args)
            except Exception as err:  # noqa: BLE001 - no message from a page may stop the server
                log.warning("dropped a message from a page (%s): %s: %s", what, type(err).__name__, err)
                return None

        return guarded

    def _clicked_scene(self, event) -> None:
        """In live mode a click on a body starts a poke there: arrows at the picked point drag its target."""
        if self.live is None or self._stop.is_set():
            return
        picked = self.pick(event.ray_origin, event.ray_direction)
        if picked is None:
            return
        body, point = picked
        self.poke(body, point, point)
        extent = float(np.ptp(self.state.rest, axis=0).max()) if self.state.n_vertices else 1.0
        handle = self.server.scene.add_transform_controls(
            "/poke/target", position=tuple(point), disable_rotations=True, scale=max(0.05, 0.4 * extent)
        )
        handle.on_update(
            self._from_page(
                "poke target",
                lambda update: self.live is not None and self.live.move(np.asarray(handle.position)),
            )
        )
        self._handles["/poke/target"] = handle
        if "release" in self._gui:
            self._gui["release"].disabled = False

    def _toggled_live(self, event, on: bool) -> None:
        if not on:
            self._released(event)
            self.stop_live()
            self._status()
            return
        self._note("Live mode: building the coarse live cages (the first time may take a minute)...")

        def start() -> None:
            try:
                self.start_live()
            except (RuntimeError, ShellsimError, ValueError) as err:
                self._notify(event.client, "Live", str(err), error=True)
                self._gui["live"].value = False
            self._note("")

        threading.Thread(target=start, name="shellsim-view-live-start", daemon=True).start()

    def _released(self, event) -> None:
        """End the poke held; with "Record pokes as pushes", add it to the scene file's edits as a push."""
        record = self.release()
        for name in ("/poke/target", "/poke/spring"):
            handle = self._handles.pop(name, None)
            if handle is not None:
                handle.remove()
        if "release" in self._gui:
            self._gui["release"].disabled = True
        record_on = self._gui.get("record")
        if record is None or record_on is None or not record_on.value or self.live is None:
            return
        try:
            action = self.live.push_action(record)
            self.editor().add_action(action)
        except (ValueError, ShellsimError) as err:
            self._notify(event.client if event else None, "Record", str(err), error=True)
            return
        self._note(
            f"Recorded a push on {action.body} at {action.start:.2f}-{action.end:.2f} s (not saved yet)"
        )

    def editor(self):
        """The :class:`shellsim.view.edit.SceneEditor` of the scene file shown (made on the first edit)."""
        from shellsim.view.edit import SceneEditor

        if self.state is None or self.state.kind != "scene":
            raise RuntimeError("editor: only a scene file is edited")
        if self._editor is None or self._editor.path != self.state.scene.resolve():
            self._editor = SceneEditor(self.state.scene)
        return self._editor

    def move(self, name: str, position, rotation) -> None:
        """Set the scene file's ``position`` [m] and ``rotation`` [degrees about world x, y, z] of the body or
        collider ``name`` (an edit, written by :meth:`save`), and move what the page shows of it rigidly to
        match; the picture and the simulation follow the file once it is saved (it is opened again)."""
        from scipy.spatial.transform import Rotation

        spec = self._pose_of(name)
        self.editor().set_pose(name, position, rotation)
        turn = Rotation.from_euler("xyz", rotation, degrees=True).as_matrix()
        turn = turn @ Rotation.from_euler("xyz", spec.rotation, degrees=True).as_matrix().T
        old, new = (
            np.asarray(self._moved.get(name, spec.position), np.float64),
            np.asarray(position, np.float64),
        )
        self._moved[name] = tuple(new)
        key = f"/bodies/{name}" if name in self._sent else f"/colliders/{name}"
        handle = self._handles.get(key)
        if name in self._sent:
            vertices = (np.asarray(self._sent[name], np.float64) - old) @ turn.T + new
            self._sent[name] = vertices.astype(np.float32)
            if handle is not None and hasattr(handle, "vertices"):
                handle.vertices = self._sent[name]
        elif handle is not None:
            handle.vertices = ((np.asarray(handle.vertices, np.float64) - old) @ turn.T + new).astype(
                np.float32
            )
        self._note(f"Moved {name} (not saved yet)")

    def save(self):
        """Write the scene file's edits (:meth:`shellsim.view.edit.SceneEditor.save`) and open it again, so
        that everything shown follows it; the saved :class:`~shellsim.shot.spec.SceneSpec`."""
        spec = self.editor().save()
        self._editor, self._moved = None, {}
        self.open(self.state.scene, self.state.out)
        return spec

    def _pose_of(self, name: str):
        """The spec (body or collider) called ``name`` as the file said it when opened."""
        spec = self.state.spec
        found = [b for b in spec.bodies if b.name == name] + [c for c in spec.colliders if c.name == name]
        if not found:
            raise ValueError(f"move: no body or collider named {name!r} in {self.state.scene}")
        return found[0]

    def _chose_to_move(self, name: str) -> None:
        """Arrows and rings at the chosen body's or collider's position (a body's: the bottom centre of its
        box); letting go of them moves it (:meth:`move`)."""
        from scipy.spatial.transform import Rotation

        old = self._handles.pop("/move", None)
        if old is not None:
            old.remove()
        if name == "(nothing)":
            return
        spec = self._pose_of(name)
        xyzw = Rotation.from_euler("xyz", spec.rotation, degrees=True).as_quat()
        extent = float(np.ptp(self.state.rest, axis=0).max()) if self.state.n_vertices else 1.0
        handle = self.server.scene.add_transform_controls(
            "/move",
            position=tuple(self._moved.get(name, spec.position)),
            wxyz=(xyzw[3], xyzw[0], xyzw[1], xyzw[2]),
            scale=max(0.05, 0.4 * extent),
        )

        def moved(event) -> None:
            w, x, y, z = handle.wxyz
            degrees = Rotation.from_quat([x, y, z, w]).as_euler("xyz", degrees=True)
            try:
                self.move(name, np.asarray(handle.position), degrees)
            except (ValueError, ShellsimError) as err:
                self._notify(event.client, "Move", str(err), error=True)

        handle.on_drag_end(self._from_page("move", moved))
        self._handles["/move"] = handle

    def _camera_from_view(self, event) -> None:
        camera = event.client.camera
        horizontal = 2.0 * np.arctan(np.tan(0.5 * camera.fov) * camera.aspect)
        try:
            name = self.editor().add_camera(
                None, np.asarray(camera.position), np.asarray(camera.look_at), float(np.degrees(horizontal))
            )
        except (ValueError, ShellsimError) as err:
            self._notify(event.client, "Camera", str(err), error=True)
            return
        self._note(f"Added the fixed camera {name} (not saved yet)")

    def _save(self, event) -> None:
        try:
            self.save()
        except (ValueError, ShellsimError) as err:
            self._notify(event.client, "Save", str(err), error=True)
            return
        self._note(f"Saved {self.state.scene}")

    def _note(self, text: str) -> None:
        """A line under the controls for what an edit or the live mode did."""
        note = self._gui.get("note")
        if note is None:
            note = self._gui["note"] = self.server.gui.add_markdown("")
        note.content = text

    def _run_live(self, generation: int) -> None:
        live = self.live
        while self._current(generation) and self.live is live and live is not None:
            start = time.perf_counter()
            live.step()
            with self._lock:
                if self.live is not live:
                    break
                displayed = []
                for body in self.state.bodies:
                    vertices, faces = live.display_mesh(body.name)
                    displayed.append((body, live.display_positions(body.name), faces))
                spring = live.spring()
                if spring is not None:
                    self._handles["/poke/spring"] = self.server.scene.add_line_segments(
                        "/poke/spring",
                        points=np.asarray([spring], np.float32),
                        colors=np.array([[[255, 80, 0], [255, 80, 0]]], np.uint8),
                        thickness=3.0,
                        thickness_units="screen",
                    )
                for body, vertices, faces in displayed:
                    name = f"/bodies/{body.name}"
                    vertices = np.asarray(vertices, np.float32)
                    self._faces[body.name] = faces
                    handle = self._handles.get(name)
                    if (
                        handle is not None
                        and hasattr(handle, "vertices")
                        and len(handle.vertices) == len(vertices)
                    ):
                        handle.vertices = vertices
                    else:
                        self._handles[name] = self.server.scene.add_mesh_simple(
                            name, vertices, faces, color=_rgb(body.color)
                        )
                    self._sent[body.name] = vertices
            time.sleep(max(0.0, 1.0 / self.live.spec.world.fps - (time.perf_counter() - start)))

    def show_picture(self, client, rgb: np.ndarray, depth: np.ndarray | None) -> None:
        """Put the neural picture ``rgb`` (H, W, 3) uint8 with ``depth`` (H, W) float32 (distance along the
        viewing axis, world units: viser's convention) as ``client``'s background, and hide the meshes it
        draws itself (bodies, colliders, ground); nothing with "Meshes only"."""
        if self._meshes_only or self._stop.is_set():
            return
        client.scene.set_background_image(rgb, depth=depth)
        self._mesh_visibility(False)

    def close(self) -> None:
        """Stop the simulation (it saves what it made), the picture, the player and the server."""
        self._stop.set()
        self._playing.clear()
        self.live = None
        self._end_background()
        if self.simulation is not None:
            self.simulation.stop()
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- drawing -----------------------------------------------------------------------------------------

    def _start_server(self) -> None:
        if self.server is not None:
            return
        viser = import_viser()
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner; the log says the URL
            self.server = viser.ViserServer(host=self.host, port=self.port, verbose=False)
        self.server.scene.set_up_direction("+z")
        self.server.on_client_connect(self._from_page("connect", self._client_connected))
        self.server.scene.on_click()(self._from_page("click", self._clicked_scene))
        if self.host not in LOCAL_HOSTS:
            log.warning(
                "serving on %s: anyone who can reach port %d can see the shot and drive the viewer "
                "(simulate, write its output)",
                self.host,
                self.server.get_port(),
            )
        log.info("viewer at %s", self.url)

    def _draw_world(self) -> None:
        state, scene = self.state, self.server.scene
        ground = state.ground()
        if ground is not None:
            for name, (vertices, faces), color in zip("ab", ground, state.look.ground_colors, strict=True):
                self._handles[f"/ground/{name}"] = scene.add_mesh_simple(
                    f"/ground/{name}",
                    vertices,
                    faces,
                    color=_rgb(color),
                    flat_shading=True,
                    cast_shadow=False,
                    side="double",
                )
        for name, vertices, faces in state.colliders:
            self._handles[f"/colliders/{name}"] = scene.add_mesh_simple(
                f"/colliders/{name}", vertices, faces, color=_rgb(state.look.obstacle_color)
            )
        extent = float(np.ptp(state.rest, axis=0).max()) if state.n_vertices else 1.0
        for camera in state.cameras:
            rotation = camera.c2w[:3, :3] * [1.0, -1.0, -1.0]  # OpenGL -> OpenCV axes (viser's)
            scene.add_camera_frustum(
                f"/cameras/{camera.name}",
                fov=camera.fov,
                aspect=camera.aspect,
                scale=max(0.03, 0.15 * extent),
                wxyz=_wxyz(rotation),
                position=camera.c2w[:3, 3],
                color=(60, 60, 60),
            )
            scene.add_label(f"/cameras/{camera.name}/label", camera.name)

    def _draw_bodies(self, displayed: list[np.ndarray]) -> None:
        """Send every body's mesh at ``displayed`` (a body with per-vertex colours as a coloured GLB, which
        is sent anew; the others' vertices are updated)."""
        import trimesh

        scene = self.server.scene
        visible = self._meshes_visible()
        for body, vertices in zip(self.state.bodies, displayed, strict=True):
            name = f"/bodies/{body.name}"
            vertices = np.asarray(vertices, np.float32)
            handle = self._handles.get(name)
            if body.colors is not None:
                colors = np.clip(np.asarray(body.colors) * 255, 0, 255).astype(np.uint8)
                mesh = trimesh.Trimesh(vertices, body.faces, vertex_colors=colors, process=False)
                handle = scene.add_mesh_trimesh(name, mesh, visible=visible)
            elif handle is not None and hasattr(handle, "vertices"):
                handle.vertices = vertices
            else:
                handle = scene.add_mesh_simple(
                    name, vertices, body.faces, color=_rgb(body.color), visible=visible
                )
            self._handles[name] = handle
            self._sent[body.name] = vertices

    def _meshes_visible(self) -> bool:
        return self.picture is None or self._meshes_only or not self._shown_picture

    def _mesh_visibility(self, visible: bool) -> None:
        """Show or hide what the neural picture draws itself: the bodies, the colliders and the ground."""
        self._shown_picture = not visible
        with self._lock:
            for name, handle in self._handles.items():
                if name.startswith(("/bodies/", "/colliders/", "/ground/")) and handle.visible != visible:
                    handle.visible = visible

    # -- the page's controls -----------------------------------------------------------------------------

    def _build_gui(self) -> None:
        gui, state = self.server.gui, self.state
        title = state.scene.name if state.scene is not None else ", ".join(b.name for b in state.bodies)
        self._gui["title"] = gui.add_markdown(f"**{title}**")
        n = state.n_frames
        slider = gui.add_slider("Frame", min=0, max=max(n - 1, 1), step=1, initial_value=0, disabled=n <= 1)
        slider.on_update(self._from_page("timeline", lambda event: self._slid(int(slider.value))))
        self._gui["frame"] = slider
        play = gui.add_button("Play", disabled=n <= 1)
        play.on_click(self._from_page("play", lambda event: self.play(not self._playing.is_set())))
        self._gui["play"] = play
        if state.kind == "scene":
            button = gui.add_button("Simulate")
            button.on_click(
                self._from_page("simulate", lambda event: self._clicked_simulate(event, overwrite=False))
            )
            self._gui["simulate"] = button
        if state.spec is not None and state.kind in ("scene", "asset"):
            live = gui.add_checkbox("Live (click a body, drag the arrows)", initial_value=False)
            live.on_update(self._from_page("live", lambda event: self._toggled_live(event, bool(live.value))))
            self._gui["live"] = live
            release = gui.add_button("Release the poke", disabled=True)
            release.on_click(self._from_page("release", self._released))
            self._gui["release"] = release
        if state.kind == "scene":
            self._gui["record"] = gui.add_checkbox("Record pokes as pushes", initial_value=False)
            movable = [b.name for b in state.spec.bodies] + [c.name for c in state.spec.colliders]
            move = gui.add_dropdown("Move", options=["(nothing)", *movable], initial_value="(nothing)")
            move.on_update(self._from_page("move", lambda event: self._chose_to_move(move.value)))
            self._gui["move"] = move
            camera = gui.add_button("Camera from this view")
            camera.on_click(self._from_page("camera from view", self._camera_from_view))
            save = gui.add_button("Save the scene file")
            save.on_click(self._from_page("save", self._save))
            self._gui["save"] = save
        self._gui["status"] = gui.add_markdown("")
        self._status()

    def _slid(self, k: int) -> None:
        if k != self._frame and 0 <= k < self.n_frames:
            self.frame(k)

    def _clicked_simulate(self, event, overwrite: bool) -> None:
        try:
            self.simulate(overwrite=overwrite)
        except (RuntimeError, ShellsimError) as err:
            self._notify(event.client, "Simulate", str(err), error=True)

    def _notify(self, client, title: str, body: str, error: bool = False) -> None:
        clients = [client] if client is not None else list(self.server.get_clients().values())
        for c in clients:
            c.add_notification(title, body, color="red" if error else "blue", auto_close_seconds=None)

    def _status(self) -> None:
        """The status line: frames, the stale motion, the simulation's progress or error."""
        state, status = self.state, self._gui.get("status")
        if status is None:
            return
        lines = []
        if state.motion is not None:
            shown = f"{state.motion.parent.name}/{state.motion.name}"
            lines.append(f"{state.n_motion} frames in `{shown}` at {state.fps:g} fps")
        if state.stale:
            lines.append(f"**Stale motion**: {state.stale}")
        sim = self.simulation
        if sim is not None:
            outcome = sim.poll()
            if outcome is None:
                lines.append("Simulating...")
            elif outcome[0] == "error":
                lines.append(f"**Simulation failed**: {outcome[1]}")
            elif outcome[0] == "done":
                lines.append("Simulation done.")
        status.content = "  \n".join(lines)
        button = self._gui.get("simulate")
        if button is not None:
            button.disabled = sim is not None and sim.poll() is None
        if state.stale and state.kind == "scene" and "anew" not in self._gui:
            anew = self.server.gui.add_button("Simulate anew (replaces the stale motion)")
            anew.on_click(
                self._from_page("simulate anew", lambda event: self._clicked_simulate(event, overwrite=True))
            )
            self._gui["anew"] = anew
        elif not state.stale and "anew" in self._gui:
            self._gui.pop("anew").remove()

    # -- background work ---------------------------------------------------------------------------------

    def _background(self, target, name: str) -> None:
        generation = self._generation
        thread = threading.Thread(
            target=target, args=(generation,), name=f"shellsim-view-{name}", daemon=True
        )
        self._threads.append(thread)
        thread.start()

    def _end_background(self) -> None:
        """Stop the threads of the target shown (a new one is opened, or the viewer closes)."""
        self._generation += 1
        self._playing.clear()
        if self.picture is not None:
            self.picture.close()
            self.picture = None
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=5.0)
        self._threads = []

    def _current(self, generation: int) -> bool:
        return generation == self._generation and not self._stop.is_set()

    def _poll(self, generation: int) -> None:
        """Every :data:`POLL_SECONDS`: the motion's frames (a run may be writing them), the simulation's
        outcome; the timeline extended, errors shown."""
        while self._current(generation):
            state = self.state
            if state.motion is not None:
                n_before = state.n_frames
                if state.refresh():
                    self._extend(n_before)
            sim = self.simulation
            if sim is not None:
                outcome = sim.poll()
                if outcome is not None and outcome is not self._reported:
                    self._reported = outcome
                    if state.refresh():
                        self._extend(state.n_frames)
                    if outcome[0] == "error":
                        log.error("simulation: %s", outcome[1])
                        self._notify(None, "Simulation failed", outcome[1], error=True)
                    else:
                        log.info("simulation %s: %d frames", outcome[0], state.n_motion)
                self._status()
            time.sleep(POLL_SECONDS)

    def _extend(self, n_before: int) -> None:
        """The timeline after the motion changed (frames added; a new motion)."""
        n = self.state.n_frames
        with self._lock:
            slider, play = self._gui.get("frame"), self._gui.get("play")
            if slider is not None:
                slider.max = max(n - 1, 1)
                slider.disabled = n <= 1
            if play is not None:
                play.disabled = n <= 1
            if self._frame >= n:
                self._frame = 0
        if n_before <= 1 < n or self._frame == 0:
            self.frame(self._frame)
        self._status()

    def _player(self, generation: int) -> None:
        while self._current(generation):
            if not self._playing.wait(timeout=0.2):
                continue
            start = time.perf_counter()
            n = self.n_frames
            if n > 1:
                self.frame((self._frame + 1) % n)
            time.sleep(max(0.0, 1.0 / self.state.fps - (time.perf_counter() - start)))

    def _compute_colors(self, generation: int) -> None:
        self.state.compute_colors(self.device)
        if self._current(generation):
            with self._lock:
                self._draw_bodies(self.state.displayed(self._frame))

    # -- the neural picture ------------------------------------------------------------------------------

    def _build_picture(self, generation: int) -> None:
        """The :class:`~shellsim.view.picture.NeuralPicture` of the state's bodies, where their fields load
        (else the meshes stay alone, said in the log); then "Meshes only" and a first picture per client."""
        from neural.errors import InputError
        from shellsim.view.picture import NeuralPicture

        state = self.state
        try:
            if state.recorded is not None:
                picture = NeuralPicture.from_scene(state.recorded, self.device)
            elif state.built is not None:
                picture = NeuralPicture.from_bodies(state.spec, state.built, self.device)
            else:
                return
        except InputError as err:
            log.warning("no neural picture (the meshes alone are shown): %s", err)
            return
        if not self._current(generation):
            picture.close()
            return
        self.picture = picture
        box = self.server.gui.add_checkbox("Meshes only", initial_value=False)
        box.on_update(self._from_page("meshes only", lambda event: self._set_meshes_only(box.value)))
        self._gui["meshes_only"] = box
        self._ask_pictures()

    def _set_meshes_only(self, on: bool) -> None:
        self._meshes_only = bool(on)
        if on:
            self._generation_picture()
            for client in self.server.get_clients().values():
                client.scene.set_background_image(None)
            self._mesh_visibility(True)
        else:
            self._ask_pictures()

    def _generation_picture(self) -> int:
        self._picture_generation += 1
        return self._picture_generation

    def _client_connected(self, client) -> None:
        self._frame_camera(client)
        client.camera.on_update(self._from_page("camera", lambda camera: self._ask_picture(client)))

    def _frame_camera(self, client) -> None:
        """Start a new page looking at the bodies from behind the scene file's first camera (its frustum in
        view), else from a three-quarter view that holds them all."""
        state = self.state
        if state is None or not state.n_vertices:
            return
        lo, hi = state.rest.min(0), state.rest.max(0)
        centre = 0.5 * (lo + hi)
        look_at = centre
        if state.cameras:  # from its side, so that its frustum stands beside the bodies, not before them
            turn = np.radians(40.0)
            about_z = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
            position = centre + 1.05 * about_z @ (state.cameras[0].c2w[:3, 3] - centre)
        else:
            reach = max(float(np.linalg.norm(hi - lo)), 0.05)
            position = centre + reach * np.array([1.2, -1.4, 1.0])
        with client.atomic():
            client.camera.up_direction = (0.0, 0.0, 1.0)
            client.camera.position = tuple(float(c) for c in position)
            client.camera.look_at = tuple(float(c) for c in look_at)

    def _ask_pictures(self) -> None:
        if self.server is None:
            return
        for client in self.server.get_clients().values():
            self._ask_picture(client)

    def _ask_picture(self, client) -> None:
        """Ask the neural picture of ``client``'s view at the frame shown (camera moved, frame changed)."""
        picture = self.picture
        if picture is None or self._meshes_only or self._stop.is_set():
            return
        generation = self._generation_picture()
        positions = self.state.positions(self._frame)
        picture.request(
            client.camera,
            positions,
            lambda rgb, depth: self._delivered(client, rgb, depth, generation),
        )

    def _delivered(self, client, rgb, depth, generation: int) -> None:
        if generation == self._picture_generation:
            self.show_picture(client, rgb, depth)


def serve(viewer: Viewer, browser: bool = True) -> None:
    """Keep ``viewer`` serving until Ctrl-C or SIGTERM (a ``KeyboardInterrupt``), opening its page in the
    web browser first with ``browser``; closes it then."""
    import webbrowser

    try:
        if browser:
            webbrowser.open(viewer.url)
        while True:
            time.sleep(1.0)
    finally:
        viewer.close()
