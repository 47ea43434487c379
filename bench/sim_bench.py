"""Benchmark of the one simulation path (:class:`shellsim.physics.solver.Solver`, driven by
:class:`shellsim.physics.driver.FrameDriver`, incremental potential contact by :mod:`shellsim.physics.ipc`):
milliseconds per implicit step against tet count, beside newton's VBD.

A 0.3 m cube of structured tets (6 per cell) falls 2 cm onto the ground while spinning, so the steps timed
include contact and friction; its boundary is its contact surface. For each size and each ``--linear-solver``
it prints the milliseconds per implicit step (one backward-Euler substep, Newton solve included), Newton
iterations and factorisations of the Newton systems (:mod:`shellsim.physics.newton_systems`) per step and the
peak resident memory; then (unless ``--no-vbd``) the same scene with the ``newton`` physics package's VBD
solver (``newton.solvers.SolverVBD``, a benchmark-only dependency: ``pip install newton``) and the time
ratio. VBD runs a fixed number of local iterations per step and does not converge the step, so the ratio
compares cost; ``--accuracy`` adds how far each ends from a run of this path converged to 1e-4 of Newton's
tolerance (VBD's contact and friction models differ too, so its figure bounds both). The figures and their
history are in docs/measurements.md.

    python bench/sim_bench.py                       # ~2k, 10k, 40k tets, rubber, CPU
    python bench/sim_bench.py --cells 7 11 --frames 3 --accuracy --linear-solver cholesky cg
    python bench/sim_bench.py --cells 12 --device cuda --material jelly
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import warp as wp

from neural.device import configure_process, processor
from shellsim.physics.driver import FrameDriver
from shellsim.physics.ipc import CONTACT_GAP, FRICTION_VELOCITY, BodySurface, Contact
from shellsim.physics.materials import get_material
from shellsim.physics.model import Model, SolverSettings
from shellsim.physics.solver import Solver
from shellsim.tetcage.geometry import boundary_faces, tet_volumes

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


def cube_surface(tets: np.ndarray, n_vertices: int) -> BodySurface:
    """The cube's boundary as its contact surface (the identity on its boundary vertices), friction 0.5."""
    import scipy.sparse as sp

    faces = boundary_faces(tets)
    used, local = np.unique(faces, return_inverse=True)
    weights = sp.csr_matrix((np.ones(len(used)), (np.arange(len(used)), used)), shape=(len(used), n_vertices))
    return BodySurface(weights, local.reshape(-1, 3), 0.5)


def bench_fem(vertices, tets, material, args, linear_solver="auto", **tolerances) -> dict:
    """Times the solver users run, or the one with ``tolerances`` (SolverSettings fields) and
    ``linear_solver`` (:class:`shellsim.physics.newton_systems.NewtonSystems`) instead."""
    settings = SolverSettings(dt=1.0 / args.fps, substeps=args.substeps, **tolerances)
    model = Model(vertices, tets, material, settings, device=args.device)
    contact = Contact(
        [cube_surface(tets, len(vertices))], [0], vertices, [], CONTACT_GAP, FRICTION_VELOCITY, 0.5
    )
    solver = Solver([model], contact, settings, linear_solver)
    state, driver = model.state((0.3, 0.0, 0.0), (0.0, 0.0, 4.0)), FrameDriver(solver)
    driver.step([state])  # compile and warm up
    steps = newton_its = 0
    factorisations = solver.systems.factorisations
    start = time.perf_counter()
    for _ in range(args.frames):
        stats = driver.step([state])
        steps += stats.substeps
        newton_its += stats.newton_iterations
    wp.synchronize_device(model.device)
    seconds = time.perf_counter() - start
    positions = state.positions.numpy()
    return {
        "ms_per_step": 1e3 * seconds / steps,
        "newton_per_step": newton_its / steps,
        "factorisations_per_step": (solver.systems.factorisations - factorisations) / steps,
        "z_min": float(positions[:, 2].min()),
        "positions": positions,
        "linear_solver": solver.systems.method,
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
    positions = state0.particle_q.numpy()
    return {
        "ms_per_step": 1e3 * seconds / (args.frames * args.substeps),
        "z_min": float(positions[:, 2].min()),
        "positions": positions,
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
        "--linear-solver",
        nargs="+",
        default=["auto"],
        choices=["auto", "cholesky", "cg"],
        help="how the Newton systems are solved, each timed (default auto: Cholesky where pypardiso loads)",
    )
    parser.add_argument(
        "--accuracy",
        action="store_true",
        help="also print how far the positions end from a run converged to 1e-4 of Newton's tolerance",
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
        f"{'tets':>7} {'verts':>6} {'linear':>8} {'ms/step':>8} {'newton/step':>11} {'factor/step':>11} "
        f"{'peak MB':>8}"
        f"{'  VBD ms/step  FEM/VBD' if vbd_available else ''}"
        f"{'  max|x - x_tight| mm (Newton tol mm)  VBD max|x - x_tight| mm' if args.accuracy else ''}"
    )
    for cells in args.cells:
        vertices, tets = cube_tets(cells)
        vbd = None
        for linear_solver in args.linear_solver:
            fem = bench_fem(vertices, tets, material, args, linear_solver)
            line = (
                f"{len(tets):7d} {len(vertices):6d} {fem['linear_solver']:>8} {fem['ms_per_step']:8.1f} "
                f"{fem['newton_per_step']:11.2f} {fem['factorisations_per_step']:11.2f} {peak_rss_mb():8.0f}"
            )
            if vbd_available:
                try:
                    vbd = vbd or bench_vbd(vertices, tets, material, args)
                    line += f"  {vbd['ms_per_step']:11.1f}  {fem['ms_per_step'] / vbd['ms_per_step']:7.2f}"
                except Exception as err:  # report, do not hide, a VBD failure: the FEM figures still stand
                    line += f"  VBD failed: {type(err).__name__}: {err}"
            if args.accuracy:
                defaults = SolverSettings()
                tight = bench_fem(
                    vertices,
                    tets,
                    material,
                    args,
                    linear_solver,
                    newton_tol=1e-4 * defaults.newton_tol,
                    newton_iterations=80,
                )
                error = 1e3 * np.abs(fem["positions"] - tight["positions"]).max()
                line += f"  {error:.4f} ({fem['tol_mm']:.4f})"
                if vbd is not None:
                    line += f"  VBD {1e3 * np.abs(vbd['positions'] - tight['positions']).max():.2f}"
            print(line, flush=True)


if __name__ == "__main__":
    configure_process()
    main()
