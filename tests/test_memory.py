"""Memory estimates (``shellsim.memory``) against the peak resident memory of real runs, and the refusals.

Each stage runs twice in a fresh process, at a small and a larger size; the growth of its peak RSS
(``resource.getrusage``) between the two is what the estimate's per-unit term must match within a factor of
2 (the estimates are linear in their unit, so a larger ask extrapolates along this slope).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from shellsim import memory
from shellsim.cli.main import main

#: Runs ``setup`` (not counted), then ``work``, and prints the resident memory before ``work`` and its
#: peak during it in bytes (``VmRSS``; ``VmHWM`` after a reset through ``clear_refs``), and the largest
#: peak of the children (``resource.getrusage``).
MEASURE = """
import json, resource
from pathlib import Path
{setup}
def status(key):
    line = next(s for s in Path("/proc/self/status").read_text().splitlines() if s.startswith(key))
    return int(line.split()[1]) * 1024
Path("/proc/self/clear_refs").write_text("5")
before = status("VmRSS:")
{work}
children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
print(json.dumps([before, status("VmHWM:"), children]))
"""


def _measure(setup: str, work: str) -> tuple[str, list[int]]:
    """(stdout, [resident before, peak during, children's peak]) of ``work`` in a fresh process."""
    code = MEASURE.format(setup=setup, work=work)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), *sys.path])}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    return done.stdout, json.loads(done.stdout.strip().splitlines()[-1])


def _peak(setup: str, work: str) -> float:
    """Bytes the resident memory grew by, at its peak, while ``work`` ran in a fresh process."""
    before, peak, _ = _measure(setup, work)[1]
    return peak - before


def _within_2(estimated: float, measured: float) -> None:
    assert 0.5 <= estimated / measured <= 2.0, (
        f"estimated {estimated / 1e6:.1f} MB, measured {measured / 1e6:.1f} MB"
    )


@pytest.mark.slow
def test_the_simulation_estimate_matches_the_peak_of_a_run(tmp_path):
    """A frame of the one simulation path: a Kuhn box set on the ground, Newton with its contact."""
    sizes = {}
    for cells in (10, 16):
        setup = f"""
import numpy as np, warp as wp
from meshes import kuhn_grid, own_surface
from shellsim.physics.driver import FrameDriver
from shellsim.physics.ipc import Contact
from shellsim.physics.materials import get_material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver
wp.init()
vertices, tets, _ = kuhn_grid((-0.1, -0.1, 0.0005), (0.1, 0.1, 0.2005), {cells})
"""
        work = """
model = Model(vertices, tets, get_material("rubber"), SolverSettings(dt=1 / 30, substeps=2), "cpu")
contact = Contact([own_surface(tets, len(vertices))], [0], vertices, [], 1e-3, 1e-2, 0.5)
FrameDriver(Solver([model], contact, model.settings)).step([model.state()])
"""
        sizes[cells] = (6 * cells**3, _peak(setup, work))
    (t1, m1), (t2, m2) = sizes[10], sizes[16]
    _within_2(memory.simulation_bytes(t2) - memory.simulation_bytes(t1), m2 - m1)


@pytest.mark.slow
def test_the_shell_estimate_matches_the_peak_of_an_extraction():
    setup = """
import dataclasses
from neural.asset import load_asset, load_field
from neural.config import ShellConfig
from neural.shell.from_field import extract_field_shells
asset = load_asset("lego")
field = load_field(asset, "cpu")
known = {f.name for f in dataclasses.fields(ShellConfig)}
stored = {k: v for k, v in asset.meta.get("shell", {}).items() if k in known}
"""
    work = 'extract_field_shells(field, ShellConfig(**{{**stored, "resolution": {r}}}), "cpu")'
    low, high = (_peak(setup, work.format(r=r)) for r in (48, 128))
    _within_2(memory.shell_bytes(128) - memory.shell_bytes(48), high - low)
    _within_2(memory.shell_bytes(128), high)


#: The LEGO drawn in the world (ground, sky, its shadow) by a camera at ``eye`` looking at its origin.
WORLD_FRAME = """
import numpy as np
from neural.asset import load_asset, load_field
from neural.data import Cameras
from shellsim.film.antialias import adaptive
from shellsim.film.renderer import DeformedRenderer
from shellsim.world import Placement, WorldLook
asset = load_asset("lego")
placement = Placement(0.13, np.eye(3), np.array([0.0, 0.0, 0.2]))
field = load_field(asset, "cpu")
renderer = DeformedRenderer(asset, field, None, "cpu", look=WorldLook(), placement=placement)
eye = np.array([0.0, -3.5, 2.0])
forward = -eye / np.linalg.norm(eye)
right = np.cross(forward, [0.0, 0.0, 1.0])
right /= np.linalg.norm(right)
c2w = np.eye(4)
c2w[:3, :3] = np.stack([right, np.cross(right, forward), -forward], 1)  # OpenGL camera: looks along -z
c2w[:3, 3] = eye
"""


@pytest.mark.slow
def test_the_render_estimate_matches_the_peak_of_a_frame():
    """Two final frames of one view (4 rays per pixel where they vary, the world's static layers kept for
    its views from the second on) at two sizes."""
    work = """n = {n}
view = Cameras(c2w[None], [n], [n], [n / 2], [n / 2], [n], [n], np.zeros((1, 4)), ["c"])
for _ in range(2):
    adaptive(renderer.tracer(), 4)(view)"""
    # the sizes RENDER_PER_PIXEL was measured between: below 512 a frame's buffers grow more slowly
    low, high = (_peak(WORLD_FRAME, work.format(n=n)) for n in (512, 1536))
    _within_2(memory.render_bytes(1536, 1536) - memory.render_bytes(512, 512), high - low)


def test_the_mesh_load_estimate_matches_the_peak_of_loading_one(tmp_path):
    for sub in (5, 7):
        trimesh.creation.icosphere(subdivisions=sub).export(tmp_path / f"{sub}.ply")
    setup = "from neural.asset import load_mesh"
    low, high = (_peak(setup, f'load_mesh("{tmp_path}/{sub}.ply")') for sub in (5, 7))
    faces = 20 * 4**7 - 20 * 4**5
    _within_2(memory.LOAD_PER_FACE * faces, high - low)


@pytest.mark.slow
def test_the_tetwild_estimate_matches_the_peak_of_its_child(tmp_path):
    setup = "import trimesh\nfrom shellsim.tetcage.tetwild import tetrahedralize\n"
    setup += "ball = trimesh.creation.icosphere(subdivisions=3)"
    work = "tets = tetrahedralize(ball.vertices, ball.faces, {edge}, 1e-3)[1]\nprint(len(tets))"
    counts, peaks = [], []
    for edge in (0.12, 0.06):
        out, (_, _, children) = _measure(setup, work.format(edge=edge))
        counts.append(int(out.split()[0]))
        peaks.append(children)
    _within_2(memory.tetwild_bytes(counts[1]) - memory.tetwild_bytes(counts[0]), peaks[1] - peaks[0])


def test_the_limit_is_what_the_machine_can_give():
    total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert 0 < memory.available_memory() <= total


def test_asking_for_more_than_the_machine_has_is_refused_before_the_work(tmp_path, capsys):
    out = tmp_path / "big.npz"
    assert main(["simulate", "--asset", "lego", "--tets", "50000000", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    head = "shellsim: error: --tets: a cage of 50,000,000 tets needs about "
    assert err.startswith(head) and "\n" not in err, err
    needed, rest = err[len(head) :].split(" GB to build and simulate; this machine has ")
    assert rest.endswith(" GB available")
    available = float(rest.split()[0])
    assert float(needed) > available > 0
    assert abs(available * 1e9 - memory.available_memory()) < 2e9
    assert list(tmp_path.iterdir()) == []  # nothing written, nothing left locked

    big = 2 * int(np.sqrt(memory.available_memory() / memory.RENDER_PER_PIXEL))
    video = f"{min(big, 16384)}x{min(big, 16384)}"
    assert (
        main(["simulate", "--asset", "lego", "--video", str(tmp_path / "v.mp4"), "--video-size", video]) == 2
    )
    assert capsys.readouterr().err.startswith(
        f"shellsim: error: --video-size: a frame of {video} pixels needs about "
    )


def test_a_run_the_machine_can_hold_is_not_refused():
    assert memory.cage_bytes(5000) < memory.available_memory()
    memory.check_memory("tets", memory.cage_bytes(5000), "a cage of 5,000 tets", "to build and simulate")


def test_a_mesh_too_large_for_the_machine_is_refused_before_it_is_tetrahedralised(
    tmp_path, capsys, monkeypatch
):
    import shellsim.tetcage.build

    trimesh.creation.box((0.1, 0.1, 0.1)).export(tmp_path / "box.ply")
    monkeypatch.setattr(memory, "available_memory", lambda device="cpu": 1_000_000)
    monkeypatch.setattr(shellsim.tetcage.build, "build_cage", lambda *a, **k: pytest.fail("tetrahedralised"))
    assert main(["simulate", "--mesh", str(tmp_path / "box.ply"), "--out", str(tmp_path / "box.npz")]) == 2
    needed = (memory.LOAD_PER_FACE + memory.TETWILD_PER_FACE) * 12 + 5000 * memory.SIM_PER_TET
    assert capsys.readouterr().err.strip() == (
        f"shellsim: error: --mesh: a mesh of 12 faces needs about {needed / 1e6:.0f} MB to tetrahedralise "
        "and simulate; this machine has 1 MB available"
    )
