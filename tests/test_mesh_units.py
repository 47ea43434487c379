"""``simulate --mesh``: the mesh is the body itself, in metres (or ``--units``), neither rescaled nor dilated.

The truth is Euler-Bernoulli's tip deflection of a cantilever under its own weight, ``rho g A L^4 / (8 E I)``.
"""

import types

import numpy as np
import pytest
import trimesh
from meshes import kuhn_grid

from shellsim.cli.main import main
from shellsim.motion.read import load_motion

G = 9.81


def beam_mesh(path, length=1.0, side=0.1):
    """A closed box ``length`` x ``side`` x ``side`` metres, from x = 0 to x = length, centred on y and z."""
    box = trimesh.creation.box((length, side, side))
    box.apply_translation([length / 2, 0.0, 0.0])
    box.export(path)
    return path


@pytest.mark.slow
def test_clamped_rubber_beam_sags_as_euler_bernoulli(tmp_path, caplog):
    """A 1 m x 0.1 m x 0.1 m beam clamped at x = 0, E = 1.5e8 Pa, rho = 1000 kg/m^3: the tip sags
    rho g A L^4 / (8 E I) = 9.81 mm. Backward-Euler steps of 25 ms (the first bending mode has 39 rad/s) and
    a little damping kill the vibration in a second; the static sag is the mean of the last second, whose
    spread is the Newton tolerance. Before the fix the beam was shrunk to 0.3 m and thickened by the cage
    margin, and sagged 1.42 mm. Coarse linear tets are stiff in bending: about 0.77 here."""
    length, side, youngs, density = 1.0, 0.1, 1.5e8, 1000.0
    expected = density * G * side**2 * length**4 / (8 * youngs * side**4 / 12)
    assert expected == pytest.approx(9.81e-3, rel=1e-3)
    out = tmp_path / "beam.npz"
    argv = [
        "simulate",
        "--mesh",
        str(beam_mesh(tmp_path / "beam.stl", length, side)),
        "--youngs",
        str(youngs),
        "--poisson",
        "0.3",
        "--density",
        str(density),
        "--no-ground",
        "--pin",
        "x<-0.48",
        "--tets",
        "1500",
        "--fps",
        "10",
        "--substeps",
        "4",
        "--damping",
        "0.01",
        "--frames",
        "20",
        "--out",
        str(out),
        "--device",
        "cpu",
    ]
    with caplog.at_level("INFO"):
        assert main(argv) == 0
    motion = load_motion(out)
    rest = motion.rest_vertices
    assert np.ptp(rest, axis=0) == pytest.approx([length, side, side], rel=0.01)  # metres, not dilated
    assert motion.placement["scale"] == 1.0  # the mesh's own metres, centred over the origin
    assert "extent 1.000 x 0.100 x 0.100 m" in caplog.text and "1 m per asset unit" in caplog.text
    tip = rest[:, 0] > length / 2 - 0.02
    last_second = (rest[tip, 2] - motion.positions[-10:, tip, 2]).mean(axis=1)  # (10,) tip sag per frame
    sag = float(last_second.mean())
    assert np.ptp(last_second) < 0.1 * sag  # at rest
    ratio = sag / expected
    print(f"tip sag {1e3 * sag:.3f} mm, Euler-Bernoulli {1e3 * expected:.3f} mm, ratio {ratio:.3f}")
    assert 0.6 <= ratio <= 1.25


@pytest.fixture
def grid_cage(monkeypatch):
    """Tetrahedralising replaced by a 48-tet box over the mesh's bounds; returns the configs asked for."""
    configs = []

    def build_cage(outer, inner, config=None, what=""):
        configs.append(config)
        lo, hi = outer.bounds
        v, t, _ = kuhn_grid(0.0, 1.0, 2)
        return types.SimpleNamespace(vertices=lo + v * (hi - lo), tets=t)

    monkeypatch.setattr("shellsim.tetcage.build.build_cage", build_cage)
    return configs


def run_box(tmp_path, *options):
    """Exit code and motion of a 2-frame fall of a 200 x 100 x 100 box mesh (units as the options say)."""
    path = tmp_path / "box.stl"
    trimesh.creation.box((200.0, 100.0, 100.0)).export(path)
    out = tmp_path / "box.npz"
    argv = ["simulate", "--mesh", str(path), "--frames", "2", "--substeps", "1", "--out", str(out)]
    code = main([*argv, "--device", "cpu", *options])
    return code, (load_motion(out) if code == 0 else None)


def test_units_scale_the_mesh_and_say_so(tmp_path, grid_cage, caplog):
    with caplog.at_level("INFO"):
        code, motion = run_box(tmp_path, "--units", "mm")
    assert code == 0
    assert motion.placement["scale"] == 0.001
    assert np.ptp(motion.rest_vertices, axis=0) == pytest.approx([0.2, 0.1, 0.1])
    assert "extent 0.200 x 0.100 x 0.100 m" in caplog.text and "0.001 m per asset unit" in caplog.text
    assert grid_cage[0].margin == 0.0  # tetrahedralised as it is, not dilated


def test_size_rescales_a_mesh_and_says_so(tmp_path, grid_cage, caplog):
    with caplog.at_level("INFO"):
        code, motion = run_box(tmp_path, "--size", "0.5")
    assert code == 0
    assert motion.placement["scale"] == pytest.approx(0.5 / 200)
    assert "extent 0.500 x 0.250 x 0.250 m" in caplog.text


@pytest.mark.parametrize(
    "options, message",
    [
        (["--units", "mm", "--size", "0.3"], "--units: "),
        (["--margin", "0.05"], "--margin: "),
        (["--size", "-1"], "--size: "),
    ],
)
def test_scale_options_that_do_not_fit_are_one_line(tmp_path, grid_cage, capsys, options, message):
    code, _ = run_box(tmp_path, *options)
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("shellsim: error: " + message) and "\n" not in err
    assert grid_cage == []  # refused before any tetrahedralising


def test_units_do_not_apply_to_an_asset(tmp_path, capsys):
    assert main(["simulate", "--asset", "lego", "--units", "mm", "--out", str(tmp_path / "m.npz")]) == 2
    assert "--units: " in capsys.readouterr().err
