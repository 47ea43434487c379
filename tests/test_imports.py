"""The light entry points stay light: each, run in a fresh interpreter, loads none of the heavy modules it
must not (torch, Warp, trimesh and pyvista load when a job runs; docs/architecture.md, "Layers")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "warp", "trimesh", "pyvista", "vtk", "pycolmap")

#: name -> (code run in a fresh interpreter, the modules it must leave unloaded)
ENTRY_POINTS = {
    # ``import shellsim``, and every settings and result class of its API resolved
    "import shellsim": (
        "import shellsim\n"
        "for name in shellsim.__all__:\n"
        "    if name.endswith(('Settings', 'Result')):\n"
        "        getattr(shellsim, name)\n",
        HEAVY,
    ),
    # ``shellsim --help`` builds every parser: the settings and their defaults come from neural.config
    "shellsim --help": (
        "import contextlib, io, shellsim.cli.main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    shellsim.cli.main.main(['--help'])\n"
        "shellsim.cli.main.build_parser()\n"
        "import shellsim.jobs.train, shellsim.jobs.extract, shellsim.jobs.cage, shellsim.jobs.poses\n"
        "import shellsim.jobs.inspect, shellsim.jobs.eval, shellsim.jobs.render\n",
        HEAVY,
    ),
    "the cage modules": (
        "import shellsim.tetcage.build, shellsim.tetcage.store, shellsim.tetcage.embed\n"
        "import shellsim.cli.commands.cage\n",
        ("torch",),
    ),
    "inspect": (
        "import shellsim.viz.inspect, shellsim.cli.commands.inspect\n",
        ("pyvista", "vtk", "torch", "warp"),
    ),
    "the physics package": ("import shellsim.physics, shellsim.physics.wind\n", ("torch",)),
}


@pytest.mark.parametrize("entry", list(ENTRY_POINTS))
def test_an_entry_point_loads_no_heavy_module(entry):
    code, forbidden = ENTRY_POINTS[entry]
    code += f"import sys\nprint(*[m for m in {forbidden!r} if m in sys.modules])\n"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split() == [], f"{entry} loads {done.stdout.strip()}"
