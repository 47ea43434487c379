"""Cost of contact between bodies: ms per substep of the LEGO-on-bunny scene against each of its bodies
simulated alone (the same world, placement and material, in the same run), and the wall time of every example
scene.

    python bench/scene_bench.py [--frames N] [--examples]

Goal (issue "Shots with several bodies"): the scene's ms per substep at most 3x the sum of the two bodies'
alone. Each run is the ``scene`` job of the command line (its cages and collision surfaces cached first, so
only the simulation is timed); a quiet machine, one job at a time.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import tomllib
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "scenes"


def toml_text(data: dict) -> str:
    """A TOML document of ``data`` (tables of numbers, strings, booleans and lists; arrays of tables)."""

    def value(v) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return json.dumps(v)

    lines = []
    for name, table in data.items():
        for entry in table if isinstance(table, list) else [table]:
            lines.append(f"[[{name}]]" if isinstance(table, list) else f"[{name}]")
            lines += [f"{k} = {value(v)}" for k, v in entry.items()]
            lines.append("")
    return "\n".join(lines)


def run(scene: Path, out: Path, frames: int | None) -> dict:
    """Run ``scene`` into ``out``; its ms per substep, Newton iterations per substep and wall seconds."""
    from shellsim.jobs.scene import SceneSettings
    from shellsim.jobs.scene import scene as run_scene

    start = time.perf_counter()
    result = run_scene(
        SceneSettings(scene=str(scene), out=str(out), frames=frames, overwrite=True), progress=False
    )
    wall = time.perf_counter() - start
    substeps = max(sum(h.substeps for h in result.history), 1)
    return {
        "frames": result.frames,
        "ms_per_substep": 1e3 * sum(h.seconds for h in result.history) / substeps,
        "newton_per_substep": sum(h.newton_iterations for h in result.history) / substeps,
        "wall_s": wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=None, help="frames of each run (default: the shot's)")
    parser.add_argument("--examples", action="store_true", help="also time every example scene, whole")
    args = parser.parse_args()
    from neural.device import configure_process

    configure_process()
    source = EXAMPLES / "lego_on_bunny.toml"
    data = tomllib.loads(source.read_text())
    with tempfile.TemporaryDirectory(prefix="scene-bench-") as tmp:
        tmp = Path(tmp)
        scenes = {"lego_on_bunny": source}
        for body in data["body"]:
            alone = {"world": data["world"], "body": [body]}
            scenes[f"{body['name']} alone"] = tmp / f"{body['name']}.toml"
            scenes[f"{body['name']} alone"].write_text(toml_text(alone))
        for path in scenes.values():  # build and cache the cages and collision surfaces, untimed
            run(path, tmp / "warm", 2)
        figures = {
            name: run(path, tmp / name.replace(" ", "_"), args.frames) for name, path in scenes.items()
        }
        for name, f in figures.items():
            print(
                f"{name:>16}: {f['ms_per_substep']:8.1f} ms per substep, {f['newton_per_substep']:.2f} "
                f"Newton iterations per substep, {f['frames']} frames in {f['wall_s']:.1f} s"
            )
        alone = sum(f["ms_per_substep"] for name, f in figures.items() if name.endswith("alone"))
        ratio = figures["lego_on_bunny"]["ms_per_substep"] / alone
        print(f"scene / (sum alone) = {ratio:.2f} (goal <= 3)")
        if args.examples:
            for path in sorted(EXAMPLES.glob("*.toml")):
                run(path, tmp / "warm", 2)
                f = run(path, tmp / path.stem, None)
                print(f"example {path.name}: {f['frames']} frames in {f['wall_s']:.1f} s")


if __name__ == "__main__":
    main()
