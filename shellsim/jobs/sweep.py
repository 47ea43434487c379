"""``shellsim sweep``: the product of materials and drop heights as simulations (plus wind strengths as wind
animations), each rendered, one sub-directory per combination, an index and a labelled contact sheet.

``OUT/<name>/`` holds ``motion.npz``, ``frames/<k:05d>.png`` (one camera for all, ``camera``, framing every
motion of the sweep, so the stills compare at one scale) and, with ``video``, ``video.mp4``; ``<name>``
is ``<material>_h<height>`` for a drop and ``wind_<strength>`` for wind.
``OUT/index.json`` lists every combination with its settings, files and figures and is rewritten as each
finishes; ``OUT/contact_sheet.png`` shows the last frame of each, labelled. Every step resumes: a motion
made with the same settings is continued (or left as it is when complete) and frames already rendered are
kept, so running the same sweep again after an interruption finishes it. With ``ray``, each combination is
a Ray task (:mod:`shellsim.distributed`).
"""

from __future__ import annotations

import functools
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shellsim.errors import SettingError
from shellsim.film.cameras import CameraSettings, camera_option
from shellsim.io.outputs import holds_outputs
from shellsim.motion.format import MAX_FRAMES
from shellsim.settings import check_range, check_required, float_list, name_list, option, pixels


@dataclass(frozen=True)
class SweepSettings:
    """What :func:`sweep` runs (module docstring)."""

    asset: str = option(help="asset directory or shipped asset name", required=True)
    out: str = option(help="directory of the sweep: one sub-directory per combination", required=True)
    material: tuple[str, ...] = option(("rubber",), help="material presets, comma-separated", parse=name_list)
    drop_height: tuple[float, ...] = option(
        (0.1,), help="drop heights in metres, comma-separated", parse=float_list
    )
    wind: tuple[float, ...] = option(
        (),
        help="also wind animations of these strengths (tip deflection / height), comma-separated",
        parse=float_list,
        shown_default="none",
    )
    frames: int = option(60, help="frames of each motion")
    size: tuple[int, int] = option(
        (512, 512), help="WxH of the frames", parse=pixels, shown_default="512x512"
    )
    video: bool = option(help="also assemble each combination's frames into an MP4")
    camera: str | None = camera_option("camera")
    orbit_degrees: float | None = camera_option("orbit_degrees")
    camera_position: tuple[float, float, float] | None = camera_option("camera_position")
    look_at: tuple[float, float, float] | None = camera_option("look_at")
    ray: str | None = option(
        help="run the combinations as Ray tasks: alone, on a local Ray instance using every core; with an "
        "ADDRESS, on that cluster ('auto': the one this machine belongs to)",
        const="local",
        metavar="ADDRESS",
    )
    device: str = option("auto", help="auto, cpu or cuda")

    def __post_init__(self):
        check_required(self)
        from shellsim.physics.materials import get_material

        for name in self.material:
            try:
                get_material(name)
            except ValueError as err:
                raise SettingError("material", str(err)) from None
        for height in self.drop_height:
            check_range("drop_height", height, 0, 100, "a height in metres")
        for strength in self.wind:
            check_range("wind", strength, 0, 1, "a tip deflection / height")
        check_range("frames", self.frames, 1, MAX_FRAMES, "an integer")
        CameraSettings.of(self)
        for name in ("material", "drop_height", "wind"):
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise SettingError(name, "each value may be given once")

    def combinations(self) -> list[dict]:
        """The runs, drops first: [{"name", "kind": "drop", "material", "drop_height"} or {"name", "kind":
        "wind", "strength"}]."""
        drops = [
            {"name": f"{m}_h{h:g}", "kind": "drop", "material": m, "drop_height": h}
            for m, h in itertools.product(self.material, self.drop_height)
        ]
        return drops + [{"name": f"wind_{w:g}", "kind": "wind", "strength": w} for w in self.wind]


@dataclass(frozen=True)
class SweepResult:
    """What :func:`sweep` made.

    out : the sweep's directory; index : ``OUT/index.json``; contact_sheet : ``OUT/contact_sheet.png``
    combinations : the index's entries, in order (drops first): ``name``, ``kind`` ("drop" or "wind"), the
        combination's settings (``material`` and ``drop_height``, or ``strength``), its files relative to
        ``out`` (``motion``, ``frames``, ``still``, ``video``: None without one) and ``render``: frames
        ``rendered`` now and ``kept``, mean ``ms``, ``samples_per_pixel`` and ``<stage>_ms`` per frame
    """

    out: Path
    index: Path
    contact_sheet: Path
    combinations: list[dict]


def simulate_combination(settings: SweepSettings, combo: dict, progress: bool = False) -> np.ndarray:
    """Simulate (or animate) one combination into ``settings.out / combo["name"] / "motion.npz"`` (continued
    when it exists with the same settings); returns the (2, 3) corners of the box its cage moves in."""
    from shellsim.jobs.simulate import SimulateSettings, simulate
    from shellsim.jobs.wind import WindSettings, wind
    from shellsim.motion.read import frame_bounds

    folder = Path(settings.out) / combo["name"]
    folder.mkdir(parents=True, exist_ok=True)
    motion = folder / "motion.npz"
    if combo["kind"] == "drop":
        drop = SimulateSettings(
            asset=settings.asset,
            material=combo["material"],
            drop_height=combo["drop_height"],
            frames=settings.frames,
            out=str(motion),
            device=settings.device,
        )
        simulate(drop, progress=progress)
    else:
        gusts = WindSettings(
            asset=settings.asset, strength=combo["strength"], frames=settings.frames, out=str(motion)
        )
        wind(gusts, progress=progress)
    return frame_bounds(motion)


def render_combination(
    settings: SweepSettings, combo: dict, framing: np.ndarray, progress: bool = False
) -> dict:
    """Render one simulated combination by the camera of ``settings``, which keeps ``framing`` (N, 3) in
    view (the same for every combination; a follow camera frames the body); returns its entry of the index:
    the combination, its files (relative to ``out``) and figures."""
    from shellsim.film.motion_frames import render_motion

    out = Path(settings.out)
    folder = out / combo["name"]
    video = folder / "video.mp4" if settings.video else None
    result = render_motion(
        settings.asset,
        folder / "motion.npz",
        folder / "frames",
        camera=CameraSettings.of(settings),
        size=settings.size,
        video=video,
        device=settings.device,
        progress=progress,
        framing=framing,
    )
    figures = {"ms": result.ms, "samples_per_pixel": result.samples_per_pixel}
    figures.update({f"{stage}_ms": ms for stage, ms in result.stage_ms.items()})
    return {
        **combo,
        "motion": f"{combo['name']}/motion.npz",
        "frames": f"{combo['name']}/frames",
        "still": f"{combo['name']}/frames/{settings.frames - 1:05d}.png",
        "video": str(video.relative_to(out)) if video else None,
        "render": {
            "rendered": result.rendered,
            "kept": result.skipped,
            **{k: round(v, 3) for k, v in figures.items() if v is not None},
        },
    }


def _recipe(step, settings: SweepSettings, *args):
    """A :func:`shellsim.distributed.run_on_ray` recipe: payload -> ``step(settings, payload, *args)``."""
    return functools.partial(_call, step, settings, args)


def _call(step, settings, args, payload):
    return step(settings, payload, *args)


def _run(settings: SweepSettings, combos: list[dict], step, args: tuple, on_result, bar, what: str) -> None:
    """``step(settings, combo, *args)`` for every combination, serially or as Ray tasks; ``on_result(i, r)``
    as each finishes."""
    bar.set_description(f"sweep: {what}")
    if settings.ray is None:
        for i, combo in enumerate(combos):
            bar.set_postfix_str(combo["name"])
            on_result(i, step(settings, combo, *args))
        return
    from shellsim.distributed import run_on_ray

    address = None if settings.ray == "local" else settings.ray
    run_on_ray(combos, functools.partial(_recipe, step, settings, *args), on_result, address)


@holds_outputs
def sweep(settings: SweepSettings, progress: bool = True) -> SweepResult:
    """Run every combination of ``settings`` (serially, or as Ray tasks with ``settings.ray``), writing
    ``OUT/index.json`` as each finishes and ``OUT/contact_sheet.png`` at the end."""
    from tqdm import tqdm

    from neural.files import write_text_atomically
    from shellsim.io.outputs import check_writable_dir, lock_output
    from shellsim.viz.contact_sheet import contact_sheet

    if settings.ray is not None:
        from shellsim.distributed import require_ray

        require_ray()  # before anything is written
    out = lock_output(check_writable_dir(settings.out, "out"), "out")
    out.mkdir(parents=True, exist_ok=True)
    combos = settings.combinations()
    index = {"asset": settings.asset, "frames": settings.frames, "combinations": [None] * len(combos)}
    bar = tqdm(total=len(combos), desc="sweep", unit="run", disable=not progress)

    def done(i: int, entry: dict) -> None:
        index["combinations"][i] = entry
        listed = {**index, "combinations": [e for e in index["combinations"] if e]}
        write_text_atomically(out / "index.json", json.dumps(listed, indent=1))
        bar.update()

    corners = [None] * len(combos)

    def simulated(i: int, box: np.ndarray) -> None:
        corners[i] = box
        bar.update()

    with bar:
        _run(settings, combos, simulate_combination, (), simulated, bar, "simulate")
        lo, hi = np.min(corners, axis=(0, 1)), np.max(corners, axis=(0, 1))  # world metres
        framing = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])  # its corners:
        # one framing for all, so the stills compare at one scale (the box's 8 corners, whatever the rotation)
        bar.reset(total=len(combos))
        _run(settings, combos, render_combination, (framing,), done, bar, "render")
    entries = index["combinations"]
    sheet = out / "contact_sheet.png"
    contact_sheet([out / e["still"] for e in entries], [e["name"] for e in entries], sheet)
    return SweepResult(out, out / "index.json", sheet, entries)
