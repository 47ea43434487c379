"""The LEGO drop exported to USD, read back by pxr and (when a Blender Python is given) imported by Blender.

Simulates (or reuses) a drop of the shipped LEGO asset, exports it with ``shellsim export --format usd``,
then prints, for the USD opened by ``pxr``: the time samples and frame range, and the largest distance
between the points of every time sample and the deformed shell / cage computed here from the motion. With
``--blender-python`` (a Python that has the ``bpy`` module, e.g. a venv with ``pip install bpy``) it imports
the stage in headless Blender and prints the scene's frame range and the vertex count and bounds of the
shell at its first and last frame.

    python bench/export_check.py --frames 24 --out /tmp/lego_drop
    python bench/export_check.py --frames 24 --out /tmp/lego_drop --blender-python /work/bpyenv/bin/python
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

import numpy as np

from neural.device import configure_process
from shellsim.cli.main import main as shellsim

BLENDER_IMPORT = """
import json, sys, bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.wm.usd_import(filepath=sys.argv[1], set_frame_range=True)
scene = bpy.context.scene
shell = next(o for o in scene.objects if o.type == "MESH" and "outer_shell" in o.name)
out = {"frame_start": scene.frame_start, "frame_end": scene.frame_end, "fps": scene.render.fps}
for frame in (scene.frame_start, scene.frame_end):
    scene.frame_set(frame)
    mesh = shell.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    zs = [v.co.z for v in mesh.vertices]
    out[f"frame_{frame}"] = {"vertices": len(mesh.vertices), "z_min": min(zs), "z_max": max(zs)}
print("BLENDER " + json.dumps(out))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--out", default="lego_drop", help="directory for the motion and the USD")
    parser.add_argument("--blender-python", help="a Python with bpy, to import the USD in headless Blender")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    motion_path, usd = out / "lego_drop.npz", out / "lego_drop.usd"
    assert (
        shellsim(["simulate", "--asset", "lego", "--frames", str(args.frames), "--out", str(motion_path)])
        == 0
    )
    t0 = time.perf_counter()
    assert (
        shellsim(
            ["export", "--asset", "lego", "--motion", str(motion_path), "--out", str(usd), "--overwrite"]
        )
        == 0
    )
    print(f"export: {time.perf_counter() - t0:.1f} s, {usd.stat().st_size / 1e6:.1f} MB")

    from pxr import Usd, UsdGeom

    from neural.asset import load_asset
    from shellsim.deform.inverse_map import deform_points
    from shellsim.motion.read import load_motion
    from shellsim.tetcage.store import cage_for_motion

    motion = load_motion(motion_path)
    asset = load_asset("lego")
    cage = cage_for_motion(asset, motion, str(motion_path))
    stage = Usd.Stage.Open(str(usd))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/outer_shell")).GetPointsAttr()
    samples = points.GetTimeSamples()
    worst = max(
        float(
            np.abs(
                np.asarray(points.Get(k))
                - deform_points(motion.positions[int(k)], cage.tets, cage.outer_tet, cage.outer_bary)
            ).max()
        )
        for k in samples
    )
    print(
        f"pxr: {len(samples)} time samples for {motion.n_frames} motion frames, range "
        f"{stage.GetStartTimeCode():g}..{stage.GetEndTimeCode():g} at {stage.GetTimeCodesPerSecond():g} fps, "
        f"up {UsdGeom.GetStageUpAxis(stage)}, {UsdGeom.GetStageMetersPerUnit(stage):.4g} m/unit, "
        f"{len(points.Get(0))} shell points, largest point error {worst:.2e}"
    )
    if args.blender_python:
        result = subprocess.run(
            [args.blender_python, "-c", BLENDER_IMPORT, str(usd.resolve())], capture_output=True, text=True
        )
        line = next((ln for ln in result.stdout.splitlines() if ln.startswith("BLENDER ")), None)
        if line is None:
            raise SystemExit(f"Blender import failed:\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}")
        print("blender:", json.dumps(json.loads(line[8:])))


if __name__ == "__main__":
    configure_process()
    main()
