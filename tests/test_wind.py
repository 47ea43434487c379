"""shellsim.physics.wind: invariants (zero wind, fixed anchor, monotone bending), the cantilever closed form,
the
inextensible-rod drop, the anchor parser, the motion file and the CLI."""

import dataclasses
import json

import numpy as np
import pytest
from meshes import kuhn_grid, save_embedded_cage, write_asset_dir

from neural.errors import InputError
from shellsim.motion.read import load_motion
from shellsim.physics.selection import parse_selection
from shellsim.physics.wind import WindField, beam_profile, heights, wind_displacement
from shellsim.tetcage.geometry import MIN_VOLUME_RATIO
from shellsim.world import Placement


def column(n_xy: int = 2, n_z: int = 8, width: float = 0.2, height: float = 1.0):
    """A box column [0, width]^2 x [0, height] split into Kuhn tets: vertices (V, 3), tets (T, 4)."""
    return kuhn_grid(0.0, (width, width, height), (n_xy, n_xy, n_z))[:2]


def rod(rng, radius, n: int = 6000):
    """Points on a vertical surface of revolution z in [-0.05, 1] with radius(z)."""
    z = rng.uniform(-0.05, 1.0, n)
    theta = rng.uniform(0.0, 2 * np.pi, n)
    r = radius(z)
    return np.stack([r * np.cos(theta), r * np.sin(theta), z], 1)


def test_zero_strength_moves_nothing_exactly(rng):
    verts, _ = column()
    settings = WindField(strength=0.0, gust=0.0, turbulence=0.7)
    for t in (0.0, 0.3, 7.1):
        assert np.array_equal(wind_displacement(verts, t, settings), np.zeros_like(verts))


def test_frame_zero_is_rest():
    verts, _ = column()
    assert np.array_equal(wind_displacement(verts, 0.0, WindField(strength=0.3)), np.zeros_like(verts))


@pytest.mark.parametrize("anchor", [None, "z<0.26", "z>0.74", "x<0.05"])
def test_anchored_vertices_never_move(anchor):
    verts, _ = column()
    settings = WindField(strength=0.2, gust=0.8, turbulence=0.5, anchor=anchor, direction=(0.3, 1.0, 0.0))
    fixed = heights(verts, settings) <= 0
    if anchor is not None:
        a = parse_selection(anchor)
        np.testing.assert_array_equal(fixed, a.sign * (verts[:, a.axis] - a.value) < 0)
    assert 0 < fixed.sum() < len(verts)
    for t in np.linspace(0.0, 5.0, 11):
        u = wind_displacement(verts, t, settings)
        assert np.array_equal(u[fixed], np.zeros_like(u[fixed]))
        assert np.abs(u[~fixed]).max() > 0 or t == 0


@pytest.mark.parametrize(
    "radius", [lambda z: 0.1 + 0 * z, lambda z: 0.02 + 0.2 * z, lambda z: 0.2 - 0.15 * z]
)
def test_displacement_grows_with_height(rng, radius):
    verts = rod(rng, radius)
    settings = WindField(strength=0.1, gust=0.4, turbulence=0.0, anchor="z<0.05")
    h = heights(verts, settings)
    order = np.argsort(h)
    for t in (0.7, 1.9):
        u = wind_displacement(verts, t, settings)
        assert np.all(np.diff(np.linalg.norm(u[order], axis=1)) >= -1e-12)


def test_uniform_rod_follows_the_cantilever_closed_form(rng):
    """EI constant, uniform load: w(h) = (h^4 - 4 L h^3 + 6 L^2 h^2) / (3 L^4) with w(L) = 1."""
    grid, w, drop, length = beam_profile(rod(rng, lambda z: 0.1 + 0 * z), WindField(anchor="z<0"))
    xi = grid / length
    np.testing.assert_allclose(w, (xi**4 - 4 * xi**3 + 6 * xi**2) / 3, atol=2e-3)
    # drop(L) = int_0^L w'^2 / 2 dh with w' = 4 xi (xi^2 - 3 xi + 3) / (3 L): 4 / (7 L)
    np.testing.assert_allclose(drop[-1] * length, 4 / 7, rtol=5e-3)


def test_thin_sections_bend_more(rng):
    """A rod half as wide in its lower half (EI 16 times lower with k = 4) against the beam equation
    w'' = M / EI integrated finely by scipy; it carries more of its deflection low than a uniform rod."""
    from scipy.integrate import cumulative_trapezoid

    settings = WindField(anchor="z<0", thinness=4.0)
    grid, w_thin, _, length = beam_profile(rod(rng, lambda z: np.where(z < 0.5, 0.05, 0.1)), settings)
    h = np.linspace(0.0, length, 4001)
    curvature = 0.5 * (length - h) ** 2 / np.where(h < 0.5, 1 / 16, 1.0)
    w = cumulative_trapezoid(cumulative_trapezoid(curvature, h, initial=0), h, initial=0)
    np.testing.assert_allclose(w_thin, np.interp(grid, h, w / w[-1]), atol=5e-3)
    _, w_uniform, _, _ = beam_profile(rod(rng, lambda z: 0.1 + 0 * z), settings)
    assert w_thin[len(grid) // 2] > w_uniform[len(grid) // 2] + 0.015


def test_bending_keeps_the_axis_length(rng):
    """The vertical drop makes a bent rod inextensible to second order in the deflection."""
    line = np.stack([np.zeros(201), np.zeros(201), np.linspace(0.0, 1.0, 201)], 1)
    verts = np.concatenate([rod(rng, lambda z: 0.1 + 0 * z), line])
    settings = WindField(strength=0.15, gust=0.0, turbulence=0.0, anchor="z<0", direction=(1.0, 0.0, 0.5))
    u = wind_displacement(verts, 10.0, settings)
    bent = line + u[-201:]
    no_drop = line + u[-201:] * [1.0, 1.0, 0.0]
    length = np.linalg.norm(np.diff(bent, axis=0), axis=1).sum()
    stretched = np.linalg.norm(np.diff(no_drop, axis=0), axis=1).sum()
    assert abs(length - 1.0) < 5e-4 < stretched - 1.0
    # without turbulence the lateral displacement is exactly along the horizontal wind direction
    np.testing.assert_allclose(u[:, 1], 0.0, atol=1e-15)
    np.testing.assert_allclose(bent[-1, 0], 0.15, rtol=1e-9)


def test_turbulence_is_frozen_and_travels_with_the_wind(rng):
    """Taylor's hypothesis: without gusts, u(x, t + tau) = u(x - c tau w_hat, t), c = wavelength L f."""
    probes = rng.uniform([-0.1, -0.1, 0.1], [0.1, 0.1, 1.0], (50, 3))
    settings = WindField(
        gust=0.0,
        turbulence=0.6,
        ramp_seconds=0.0,
        frequency=0.7,
        wavelength=0.5,
        anchor="z<0",
        direction=(1.0, 1.0, 0.3),
    )
    w_hat = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    tau, length = 0.3, 1.0
    shift = settings.wavelength * length * settings.frequency * tau * w_hat
    verts = np.concatenate([rod(rng, lambda z: 0.1 + 0 * z), probes, probes - shift, [[0.0, 0.0, length]]])
    assert heights(verts, settings).max() == length
    n = len(probes)
    later = wind_displacement(verts, 2.0 + tau, settings)[-2 * n - 1 : -n - 1]
    earlier = wind_displacement(verts, 2.0, settings)[-n - 1 : -1]
    np.testing.assert_allclose(later, earlier, atol=1e-12)
    assert np.abs(later - wind_displacement(verts, 2.0, settings)[-2 * n - 1 : -n - 1]).max() > 1e-3


def test_settings_are_validated():
    with pytest.raises(InputError, match=r"strength: expected 0 <= strength <= 1, got -1$"):
        WindField(strength=-1.0)
    with pytest.raises(InputError, match=r"strength: expected 0 <= strength <= 1, got 5$"):
        WindField(strength=5.0)
    with pytest.raises(InputError, match=r"gust: expected 0 <= gust <= 1, got nan$"):
        WindField(gust=float("nan"))
    with pytest.raises(InputError, match="seed"):
        WindField(seed=-1)
    with pytest.raises(InputError, match="direction"):
        WindField(direction=(0.0, 0.0, 0.0))
    with pytest.raises(InputError, match=r"direction 0, 0, 1 is along the object's bending axis 0, 0, 1:"):
        WindField(direction=np.array([0.0, 0.0, 2.0]))
    with pytest.raises(InputError, match=r"^anchor 'z<<1': expected AXIS OP VALUE"):
        WindField(anchor="z<<1")
    verts, _ = column()
    with pytest.raises(InputError, match=r"^anchor: 'z<-1' selects no cage vertex \(z spans 0 .. 1\)$"):
        heights(verts, WindField(anchor="z<-1"))
    with pytest.raises(InputError, match="selects every cage vertex"):
        heights(verts, WindField(anchor="z<5"))


def _wind_motion(tmp_path, name: str, frames: int, fps: float, **wind):
    """The wind job's motion of the rod asset (its cage a column of Kuhn tets, no fTetWild run) with the
    wind settings ``wind``, and the wind field the job used."""
    from neural.asset import load_asset
    from shellsim.jobs.wind import WindSettings
    from shellsim.jobs.wind import wind as run_wind

    root = tmp_path / "rod"
    if not (root / "cage.npz").exists():
        asset = load_asset(_write_asset(root))
        verts, tets = column(n_xy=2, n_z=6, width=0.4, height=1.1)
        save_embedded_cage(asset, verts - [0.2, 0.2, 0.05], tets)
    settings = WindSettings(asset=str(root), frames=frames, fps=fps, out=str(tmp_path / name), **wind)
    run_wind(settings, progress=False)
    return load_motion(tmp_path / name), settings.field((0.0, 0.0, 1.0))


def test_the_wind_job_writes_the_analytic_wind_and_resumes_it_exactly(tmp_path):
    motion, field = _wind_motion(tmp_path, "wind.npz", 10, 24.0, strength=0.1)
    rest = motion.rest_vertices
    assert motion.positions.shape == (10, len(rest), 3)
    np.testing.assert_allclose(motion.times, np.arange(10) / 24.0)
    np.testing.assert_array_equal(motion.positions[0], rest.astype(np.float32))
    np.testing.assert_allclose(
        motion.positions[7], rest + wind_displacement(rest, 7 / 24.0, field), atol=1e-6
    )
    assert motion.settings["model"] == "analytic cantilever wind"
    assert motion.settings["strength"] == 0.1 and motion.settings["fps"] == 24.0
    stats = motion.meta["stats"]
    assert stats["frames"] == 10 and 0 < stats["min_volume_ratio"] < 1 and stats["limited_frames"] == 0
    json.dumps(motion.meta)

    # resuming continues where the file stops and gives the same frames as one run
    _wind_motion(tmp_path, "short.npz", 4, 24.0, strength=0.1)
    resumed, _ = _wind_motion(tmp_path, "short.npz", 10, 24.0, strength=0.1)
    np.testing.assert_array_equal(resumed.positions, motion.positions)
    np.testing.assert_array_equal(resumed.times, motion.times)
    with pytest.raises(InputError, match=r"made with other settings \(strength: 0.1 -> 0.2\)"):
        _wind_motion(tmp_path, "short.npz", 12, 24.0, strength=0.2)
    assert load_motion(tmp_path / "short.npz").n_frames == 10


def _ratios(rest, positions, tets):
    """(T,) deformed / rest tet volumes from 3x3 determinants."""

    def det(x):
        return np.linalg.det(np.stack([x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)], axis=2))

    return det(positions) / det(rest)


def test_a_wind_too_strong_for_the_cage_is_limited_never_folds_it(tmp_path):
    """Full strength, gusts and turbulence fold a column's tets (volume ratio 1 - slope^2 / 2 < 0 at the
    top); every written frame keeps them above the floor, the frames that fit are the analytic wind, and
    a limited frame is the analytic wind of a lower strength: the same bent shape, scaled."""
    wind = dict(strength=1.0, gust=1.0, turbulence=1.0, frequency=1.0, direction=(1.0, 0.3, 0.0))
    fps, frames = 10.0, 24
    motion, settings = _wind_motion(tmp_path, "wind.npz", frames, fps, **wind)
    verts, tets = motion.rest_vertices, motion.tets
    assert motion.n_frames == frames
    unlimited = [
        _ratios(verts, verts + wind_displacement(verts, i / fps, settings), tets).min() for i in range(frames)
    ]
    assert min(unlimited) < 0  # the analytic wind inverts tets in some frames
    written = np.array([_ratios(verts, p.astype(np.float64), tets).min() for p in motion.positions])
    assert written.min() >= MIN_VOLUME_RATIO - 1e-4  # float32 positions
    stats = motion.meta["stats"]
    assert stats["limited_frames"] == sum(r < MIN_VOLUME_RATIO for r in unlimited) > 0
    top = np.argmax(verts[:, 2])
    wind_hat = np.array([1.0, 0.3, 0.0]) / np.linalg.norm([1.0, 0.3, 0.0])
    for i in range(frames):
        t = i / fps
        full = wind_displacement(verts, t, settings)
        u = motion.positions[i].astype(np.float64) - verts
        if unlimited[i] >= MIN_VOLUME_RATIO:
            np.testing.assert_allclose(u, full, atol=1e-6)
            continue
        scale = (u[top] @ wind_hat) / (full[top] @ wind_hat)
        assert 0 < scale < 1
        weaker = wind_displacement(verts, t, dataclasses.replace(settings, strength=scale))
        np.testing.assert_allclose(u, weaker, atol=1e-5)
        # bent as far as the floor allows, not further back
        assert written[i] < MIN_VOLUME_RATIO + 2e-3
    assert stats["min_bend_scale"] < 1 and stats["min_volume_ratio"] >= MIN_VOLUME_RATIO - 1e-9


def _write_asset(root):
    """A minimal asset: asset.json, a placeholder field file and closed cylinder shells (z up)."""
    import trimesh

    outer = trimesh.creation.cylinder(radius=0.15, height=1.0, sections=24)
    outer.apply_translation([0.0, 0.0, 0.5])
    inner = trimesh.creation.cylinder(radius=0.1, height=0.9, sections=24)
    inner.apply_translation([0.0, 0.0, 0.5])
    return write_asset_dir(root, outer, inner, "rod", center=(0, 0, 0.5), up=(0, 0, 1))


def test_cli_rejects_a_junk_anchor(tmp_path, capsys):
    from shellsim.cli.main import main

    asset = _write_asset(tmp_path / "rod")
    assert main(["wind", "--asset", str(asset), "--anchor", "z<__import__('os')"]) == 2
    assert "anchor" in capsys.readouterr().err
    assert main(["wind", "--asset", str(asset), "--direction", "1,0"]) == 2
    assert "--direction" in capsys.readouterr().err


@pytest.mark.parametrize(
    "option, message",
    [
        (["--strength", "5"], "--strength: expected a tip deflection / height in [0, 1], got 5"),
        (["--strength", "-1"], "--strength: expected a tip deflection / height in [0, 1], got -1"),
        (["--gust", "1.5"], "--gust: expected a relative amplitude in [0, 1], got 1.5"),
        (["--turbulence", "nan"], "--turbulence: expected a relative amplitude in [0, 1], got nan"),
        (["--seed", "-3"], "--seed: expected an integer in [0, 4294967295], got -3"),
        (["--frames", "0"], "--frames: expected an integer in [1, 10000], got 0"),
        (["--frames", "100000000"], "--frames: expected an integer in [1, 10000], got 100000000"),
        (["--fps", "0"], "--fps: expected a number of frames per second in (0, 1000], got 0"),
        (
            ["--fps", "12", "--frequency", "2.5"],
            "--frequency: expected a number of Hz in [0, 10] and at most 2 ",
        ),
        (["--fps", "2"], "--frequency: expected a number of Hz in [0, 10] and at most 0.3333 "),
    ],
)
def test_cli_refuses_out_of_range_numbers_before_loading(tmp_path, capsys, option, message):
    """Refused with the valid range before the asset is read: the asset does not even exist."""
    from shellsim.cli.main import main

    assert main(["wind", "--asset", str(tmp_path / "missing"), *option]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"shellsim: error: {message}") and "\n" not in err


def test_cli_direction_along_the_axis_reads_plain_numbers(tmp_path, capsys):
    from shellsim.cli.main import main

    asset = _write_asset(tmp_path / "rod")
    assert main(["wind", "--asset", str(asset), "--direction", "0,0,1"]) == 2
    err = capsys.readouterr().err
    assert "direction 0, 0, 1 is along the object's bending axis 0, 0, 1" in err and "float64" not in err


def test_cli_writes_and_resumes(tmp_path):
    """The CLI on an asset whose cage.npz is a box of Kuhn tets around the shells (no fTetWild run)."""
    from neural.asset import load_asset
    from shellsim.cli.main import main

    asset = load_asset(_write_asset(tmp_path / "rod"))
    verts, tets = column(n_xy=2, n_z=6, width=0.4, height=1.1)
    verts -= [0.2, 0.2, 0.05]
    save_embedded_cage(asset, verts, tets)
    out = tmp_path / "wind.npz"
    args = ["wind", "--asset", str(asset.root), "--fps", "10", "--out", str(out), "--anchor", "z<0.1"]
    assert main([*args, "--frames", "3"]) == 0
    assert main([*args, "--frames", "5", "--resume"]) == 0
    motion = load_motion(out)
    assert motion.n_frames == 5 and motion.asset["name"] == "rod" and motion.producer == "shellsim wind"
    # the rod stands on the ground in metres: 1.1 units tall scaled to 0.3 m, centred over the origin
    rest = motion.rest_vertices
    assert np.ptp(rest, axis=0) == pytest.approx(np.ptp(verts, axis=0) * 0.3 / 1.1)
    assert rest[:, 2].min() == pytest.approx(0.0) and motion.placement["scale"] == pytest.approx(0.3 / 1.1)
    np.testing.assert_allclose(Placement.from_dict(motion.placement, "m").to_asset(rest), verts, atol=1e-12)
    np.testing.assert_allclose(motion.times, np.arange(5) / 10)
    assert np.array_equal(motion.positions[0], rest.astype(np.float32))
    anchored = rest[:, 2] < 0.1
    np.testing.assert_array_equal(
        motion.positions[:, anchored],
        np.broadcast_to(rest[anchored], (5, anchored.sum(), 3)).astype(np.float32),
    )
    assert np.abs(motion.positions[4] - rest).max() > 1e-3
    assert main([*args, "--frames", "6", "--resume", "--strength", "0.2"]) == 2  # other settings
    assert load_motion(out).n_frames == 5
