"""Benchmark of the implicit FEM (:mod:`shellsim.physics.solver`, driven by :mod:`shellsim.physics.driver`):
milliseconds per implicit step against tet count.

A 0.3 m cube of structured tets (6 per cell) falls 2 cm onto the ground while spinning, so the steps timed
include contact and friction. For each size it prints the milliseconds per implicit step (one backward-Euler
substep, Newton solve included), Newton iterations per step, tet Hessians per step (the Newton iterations that
evaluated the tets' blocks: the others of a substep reuse them,
``shellsim.physics.solver.ELASTIC_HESSIAN_REUSE``), CG iterations per Newton iteration and the peak resident
memory, then (unless ``--no-vbd``) the same scene with
the ``newton`` physics package's VBD solver (``newton.solvers.SolverVBD``, a benchmark-only dependency:
``pip install newton``) and the time ratio.
VBD runs a fixed number of local iterations per step and does not converge the step, so the ratio compares
cost, not accuracy.

Measured 2026-12-02 on the shared 2-core CPU under load average 4-6 (the lower of two runs, rubber, newton 1.8
VBD): FEM 7.9 / 35.2 / 254.6 ms per step at 2k / 10k / 41k tets (2.9-3.2 Newton iterations per step,
17.5 / 26.3 / 40.7 CG steps per Newton step), 0.42 / 0.45 / 0.80 of VBD's time; the code before SSOR and the
leaner evaluation passes, run just before in the same conditions: 11.0 / 58.6 / 373.4 ms (21.4 / 35.7 / 57.5
CG steps), 0.49-0.58 / 0.80-0.92 / 1.12-1.28 of VBD's. Absolute figures on this machine swing by 1.5-3x
with its load; the FEM/VBD ratio, measured side by side, is the steadier figure. Night of 2026-12-02, with
the last Newton step taken and inexact Newton (two runs): 6.9-8.3 / 26.2-29.5 / 107-133 ms, 11.9 / 16.9 /
29.2 CG steps per Newton step, 0.34-0.36 / 0.44-0.48 / 0.40 of VBD's time; ``--accuracy``: positions 0.0074 /
0.0032 / 0.0020 mm from a tightly converged run, where the code before ended 0.20 / 0.25 / 0.24 mm away.
Afternoon of 2026-12-03, with the tets' Hessian blocks reused within a substep (a machine about 1.7x slower
than that night): 11.1 / 47.6 / 253.5 ms, 1.62 / 1.71 / 1.71 tet Hessians per step (2.92 / 3.08 / 2.71
before), the same Newton and CG counts and accuracy, 0.37 / 0.54 / 1.00 of VBD's time.

    python bench/sim_bench.py                       # ~2k, 10k, 40k tets, rubber, CPU
    python bench/sim_bench.py --cells 12 --device cuda --material jelly
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import warp as wp

from neural.device import configure_process, processor
from shellsim.cage.geometry import tet_volumes
from shellsim.physics.control import Control
from shellsim.physics.driver import FrameDriver
from shellsim.physics.materials import get_material
from shellsim.physics.model import Model, SimSettings

SIZE = 0.3  # metres
LIFT = 0.02  # metres above the ground


def cube_tets(cells: int) -> tuple[np.ndarray, np.ndarray]:
    """A SIZE cube of cells^3 cubes, 6 tets each (Kuhn split), lifted LIFT above z = 0."""
    axis = np.linspace(0.0, SIZE, cells + 1)
    vertices = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    vertices[:, :2] -= SIZE / 2
    vertices[:, 2] += LIFT
    i, j, k = (a.ravel() for a in np.meshgrid(*[np.arange(cells)] * 3, indexing="ij"))
    m = cells + 1
    corner = [((i + a) * m + j + b) * m + k + d for a in (0, 1) for b in (0, 1) for d in (0, 1)]
    tets = np.concatenate(
        [
            np.stack([corner[0], corner[p], corner[q], corner[7]], 1)
            for p, q in ((4, 6), (4, 5), (2, 6), (2, 3), (1, 5), (1, 3))
        ]
    )
    flip = tet_volumes(vertices, tets) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return vertices, tets


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_fem(vertices, tets, material, args, **tolerances) -> dict:
    """Times the default solver, or the one with ``tolerances`` (SimSettings fields) instead."""
    settings = SimSettings(dt=1.0 / args.fps, substeps=args.substeps, ground=0.0, **tolerances)
    model = Model(vertices, tets, material, settings, device=args.device)
    state, control, driver = model.state((0.3, 0.0, 0.0), (0.0, 0.0, 4.0)), Control(model), FrameDriver(model)
    driver.step(state, control)  # compile and warm up
    steps = newton_its = cg_its = hessians = 0
    start = time.perf_counter()
    for _ in range(args.frames):
        stats = driver.step(state, control)
        steps += stats.substeps
        newton_its += stats.newton_iterations
        cg_its += stats.cg_iterations
        hessians += stats.hessians
    wp.synchronize_device(model.device)
    seconds = time.perf_counter() - start
    positions = state.positions.numpy()
    return {
        "ms_per_step": 1e3 * seconds / steps,
        "newton_per_step": newton_its / steps,
        "hessians_per_step": hessians / steps,
        "cg_per_newton": cg_its / max(newton_its, 1),
        "z_min": float(positions[:, 2].min()),
        "positions": positions,
        "tol_mm": 1e3 * settings.newton_tol * model.size * settings.dt / settings.substeps,
    }


def bench_vbd(vertices, tets, material, args) -> dict:
    import newton

    builder = newton.ModelBuilder()
    builder.add_ground_plane()
    builder.add_soft_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(0.3, 0.0, 0.0),
        vertices=[wp.vec3(*p) for p in vertices],
        indices=tets.ravel().tolist(),
        density=material.density,
        k_mu=material.mu,
        k_lambda=material.lam,
        k_damp=0.0,
    )
    builder.color()
    model = builder.finalize(device=args.device)
    solver = newton.solvers.SolverVBD(model, iterations=args.vbd_iterations, particle_enable_tile_solve=False)
    state0, state1 = model.state(), model.state()
    # the same spin as the FEM run, about the cube's vertical axis
    x = state0.particle_q.numpy()
    spin = np.cross([0.0, 0.0, 4.0], x - x.mean(0)) + [0.3, 0.0, 0.0]
    state0.particle_qd.assign(wp.array(spin, dtype=wp.vec3, device=model.device))
    control = model.control()
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    dt = 1.0 / args.fps / args.substeps

    def frame():
        nonlocal state0, state1
        for _ in range(args.substeps):
            state0.clear_forces()
            pipeline.collide(state0, contacts)
            solver.step(state0, state1, control, contacts, dt)
            state0, state1 = state1, state0

    frame()  # compile and warm up
    start = time.perf_counter()
    for _ in range(args.frames):
        frame()
    wp.synchronize_device(model.device)
    seconds = time.perf_counter() - start
    return {
        "ms_per_step": 1e3 * seconds / (args.frames * args.substeps),
        "z_min": float(state0.particle_q.numpy()[:, 2].min()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--cells",
        type=int,
        nargs="+",
        default=[7, 12, 19],
        help="cells per cube side; 6 cells^3 tets (default 7 12 19: ~2k, 10k, 40k tets)",
    )
    parser.add_argument("--material", default="rubber")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--frames", type=int, default=3, help="frames timed after one warm-up frame")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--vbd-iterations", type=int, default=10)
    parser.add_argument("--no-vbd", action="store_true", help="skip the newton VBD comparison")
    parser.add_argument(
        "--accuracy",
        action="store_true",
        help="also print how far the positions end from a run converged to 1e-4 of the tolerances",
    )
    args = parser.parse_args()
    wp.config.quiet = True
    wp.init()
    material = get_material(args.material)
    print(
        f"device {args.device} ({processor(args.device)}), {args.material} (E={material.youngs:g} Pa, "
        f"nu={material.poisson}), "
        f"{args.fps:g} fps x {args.substeps} substeps, {args.frames} frames timed"
    )
    vbd_available = not args.no_vbd
    if vbd_available:
        try:
            import newton  # noqa: F401
        except ImportError as err:
            print(
                f"newton VBD comparison skipped: the 'newton' package is not installed ({err}); "
                "pip install newton"
            )
            vbd_available = False
    print(
        f"{'tets':>7} {'verts':>6} {'ms/step':>8} {'newton/step':>11} {'tet H/step':>10} {'cg/newton':>9} "
        f"{'peak MB':>8}"
        f"{'  VBD ms/step  FEM/VBD' if vbd_available else ''}"
        f"{'  max|x - x_tight| mm (Newton tol mm)' if args.accuracy else ''}"
    )
    for cells in args.cells:
        vertices, tets = cube_tets(cells)
        fem = bench_fem(vertices, tets, material, args)
        line = (
            f"{len(tets):7d} {len(vertices):6d} {fem['ms_per_step']:8.1f} {fem['newton_per_step']:11.2f} "
            f"{fem['hessians_per_step']:10.2f} {fem['cg_per_newton']:9.1f} {peak_rss_mb():8.0f}"
        )
        if vbd_available:
            try:
                vbd = bench_vbd(vertices, tets, material, args)
                line += f"  {vbd['ms_per_step']:11.1f}  {fem['ms_per_step'] / vbd['ms_per_step']:7.2f}"
            except Exception as err:  # report, do not hide, a VBD failure: the FEM figures still stand
                line += f"  VBD failed: {type(err).__name__}: {err}"
        if args.accuracy:
            defaults = SimSettings()
            tight = bench_fem(
                vertices,
                tets,
                material,
                args,
                newton_tol=1e-4 * defaults.newton_tol,
                cg_tol=1e-4 * defaults.cg_tol,
                newton_iterations=50,
            )
            error = 1e3 * np.abs(fem["positions"] - tight["positions"]).max()
            line += f"  {error:.4f} ({fem['tol_mm']:.4f})"
        print(line, flush=True)


if __name__ == "__main__":
    configure_process()
    main()
