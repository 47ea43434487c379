"""Linear solvers for the Newton steps of :mod:`shellsim.physics.solver`: the block-sparse (3x3, CSR)
stiffness pattern (:func:`block_topology`), a serial SSOR-preconditioned CG that runs the whole loop
in one Warp kernel (the CPU path, :func:`serial_pcg_solver`), and the CUDA path (:func:`bsr_cg_solver`):
:func:`warp.optim.linear.cg` on a :mod:`warp.sparse` BSR matrix sharing that pattern, with a block-Jacobi
preconditioner. Each factory returns ``solve(atol, rtol) -> CG iterations`` solving ``H d = b`` in place
from the guess in ``d`` to ``|b - H d| <= max(rtol |b|, atol)`` (the CUDA path fixes ``rtol`` at creation).
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # no autodiff here; halves compile time

vec3 = wp.vec3d
mat33 = wp.mat33d
f64 = wp.float64

# over-relaxation of the serial PCG's SSOR: 25-30% fewer CG steps than 1 (SGS) on the 2k-41k-tet bench cubes
SSOR_OMEGA = 1.4


@wp.func
def row_product(
    values: wp.array(dtype=mat33),
    columns: wp.array(dtype=wp.int32),
    x: wp.array(dtype=vec3),
    start: int,
    end: int,
) -> vec3:
    """sum over blocks k in [start, end) of values[k] x[columns[k]], in two interleaved sums (half the
    dependency chain of one running sum)."""
    even = vec3(f64(0.0), f64(0.0), f64(0.0))
    odd = vec3(f64(0.0), f64(0.0), f64(0.0))
    k = start
    while k + 1 < end:
        even += values[k] * x[columns[k]]
        odd += values[k + 1] * x[columns[k + 1]]
        k += 2
    if k < end:
        even += values[k] * x[columns[k]]
    return even + odd


@wp.func
def residual(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat33),
    b: wp.array(dtype=vec3),
    x: wp.array(dtype=vec3),
    r: wp.array(dtype=vec3),
) -> f64:
    """r = b - A x; returns |r|^2."""
    rr = f64(0.0)
    for i in range(b.shape[0]):
        acc = b[i] - row_product(values, columns, x, offsets[i], offsets[i + 1])
        r[i] = acc
        rr += wp.dot(acc, acc)
    return rr


@wp.func
def upper_solve(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat33),
    diag_index: wp.array(dtype=wp.int32),
    inv_diag: wp.array(dtype=mat33),
    omega: f64,
    z: wp.array(dtype=vec3),
    beta: f64,
    p: wp.array(dtype=vec3),
    t: wp.array(dtype=vec3),
    u: wp.array(dtype=vec3),
):
    """p = z + beta p, then t = (D / omega + U)^-1 p (backward substitution over the upper blocks), keeping
    u = p - U t (= D t / omega)."""
    n = p.shape[0]
    for j in range(n):
        i = n - 1 - j
        pi = z[i] + beta * p[i]
        p[i] = pi
        acc = pi - row_product(values, columns, t, diag_index[i] + 1, offsets[i + 1])
        u[i] = acc
        t[i] = omega * (inv_diag[i] * acc)
    return 0


@wp.func
def lower_solve(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat33),
    diag_index: wp.array(dtype=wp.int32),
    inv_diag: wp.array(dtype=mat33),
    omega: f64,
    p: wp.array(dtype=vec3),
    t: wp.array(dtype=vec3),
    s: wp.array(dtype=vec3),
    q: wp.array(dtype=vec3),
) -> f64:
    """s = (D / omega + L)^-1 (p - (2 / omega - 1) D t) (forward substitution over the lower blocks), with
    ``D t / omega`` read from ``q`` (:func:`upper_solve`'s u), then q = t + s; returns p . q."""
    pq = f64(0.0)
    for i in range(p.shape[0]):
        acc = p[i] - (f64(2.0) - omega) * q[i] - row_product(values, columns, s, offsets[i], diag_index[i])
        si = omega * (inv_diag[i] * acc)
        s[i] = si
        qi = t[i] + si
        q[i] = qi
        pq += wp.dot(p[i], qi)
    return pq


@wp.kernel
def pcg_serial(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat33),
    diag_index: wp.array(dtype=wp.int32),
    inv_diag: wp.array(dtype=mat33),
    b: wp.array(dtype=vec3),
    tol: f64,
    atol: f64,
    max_iter: int,
    omega: f64,
    x: wp.array(dtype=vec3),
    r: wp.array(dtype=vec3),
    z: wp.array(dtype=vec3),
    p: wp.array(dtype=vec3),
    q: wp.array(dtype=vec3),
    t: wp.array(dtype=vec3),
    result: wp.array(dtype=f64),
):
    """SSOR-preconditioned CG for ``A x = b`` from the guess in ``x``, the whole loop in one thread, with
    Eisenstat's trick: with the blocks ``A = L + D + U``, ``D' = D / omega`` and
    ``M = (D' + L) D'^-1 (D' + U)`` (``omega = 1``: symmetric Gauss-Seidel), CG runs on
    ``K = (D' + L)^-1 A (D' + U)^-1`` preconditioned by ``D'^-1`` (the same iterates), whose product
    ``K p = t + (D' + L)^-1 (p - (2 D' - D) t)``, ``t = (D' + U)^-1 p``, is one sweep over the blocks, where a
    product with ``A`` and the two sweeps of ``M^-1`` are two; ``x`` moves by ``t`` per unit of the
    transformed step (``inv_diag`` holds ``D^-1``; ``z`` is scaled by ``omega``, which leaves CG unchanged).

    ``r`` holds ``(D' + L)^-1 (b - A x)``, so ``r . z = omega (b - A x)^T M^-1 (b - A x)``; that times the
    ratio ``|b - A x|^2 / r . z`` of the last exact residual estimates ``|b - A x|^2``, and an exact residual
    (one product with ``A``) confirms ``|b - A x| <= max(tol |b|, atol)`` before it stops.
    ``result`` = (iterations, |b - A x| / |b|)."""
    n = b.shape[0]
    bb = f64(0.0)
    xx = f64(0.0)
    zero = vec3(f64(0.0), f64(0.0), f64(0.0))
    for i in range(n):
        bb += wp.dot(b[i], b[i])
        xx += wp.dot(x[i], x[i])
        t[i] = zero
        z[i] = zero
        p[i] = zero
    rr = bb  # the residual of a zero guess, without the product with A
    if xx > f64(0.0):
        rr = residual(offsets, columns, values, b, x, q)
    else:
        for i in range(n):
            q[i] = b[i]
    lower_solve(offsets, columns, values, diag_index, inv_diag, omega, q, t, r, z)
    rz = f64(0.0)
    for i in range(n):
        zi = values[diag_index[i]] * r[i]
        z[i] = zi
        rz += wp.dot(r[i], zi)
    ratio = rr / wp.max(rz, f64(1.0e-300))
    threshold = wp.max(tol * tol * bb, atol * atol)
    beta = f64(0.0)  # p = z first
    it = int(0)  # noqa: UP018 (a mutable Warp variable, not a constant)
    while it < max_iter and rr > threshold:
        upper_solve(offsets, columns, values, diag_index, inv_diag, omega, z, beta, p, t, q)
        pq = lower_solve(offsets, columns, values, diag_index, inv_diag, omega, p, t, z, q)
        if pq <= f64(0.0):
            break
        alpha = rz / pq
        rz_new = f64(0.0)
        for i in range(n):
            x[i] = x[i] + alpha * t[i]
            ri = r[i] - alpha * q[i]
            r[i] = ri
            zi = values[diag_index[i]] * ri
            z[i] = zi
            rz_new += wp.dot(ri, zi)
        it += 1
        rr = ratio * rz_new
        if rr <= threshold:
            rr = residual(offsets, columns, values, b, x, q)
            ratio = rr / wp.max(rz_new, f64(1.0e-300))
        beta = rz_new / rz
        rz = rz_new
    result[0] = f64(it)
    result[1] = wp.sqrt(rr / wp.max(bb, f64(1.0e-300)))


@wp.kernel
def apply_block_jacobi(
    inv_diag: wp.array(dtype=mat33),
    x: wp.array(dtype=vec3),
    y: wp.array(dtype=vec3),
    z: wp.array(dtype=vec3),
    alpha: f64,
    beta: f64,
):
    """z = alpha blockdiag^-1 x + beta y (the preconditioner of :func:`warp.optim.linear.cg`)."""
    i = wp.tid()
    z[i] = alpha * (inv_diag[i] * x[i]) + beta * y[i]


def block_topology(tets: np.ndarray, n_vertices: int):
    """Sparsity of the stiffness matrix: CSR ``offsets`` (V+1,), block ``columns`` (nnz,), the block slot of
    every (tet, a, b) pair ``block_index`` (T, 16) and of every diagonal block ``diag_index`` (V,)."""
    rows = np.repeat(tets, 4, axis=1)  # (T, 16): a repeated
    cols = np.tile(tets, (1, 4))  # (T, 16): b cycling
    keys = rows.astype(np.int64) * n_vertices + cols
    unique, inverse = np.unique(keys.ravel(), return_inverse=True)
    urows, ucols = np.divmod(unique, n_vertices)
    offsets = np.zeros(n_vertices + 1, np.int64)
    np.cumsum(np.bincount(urows, minlength=n_vertices), out=offsets[1:])
    diag_index = np.searchsorted(unique, np.arange(n_vertices, dtype=np.int64) * (n_vertices + 1))
    return (
        offsets.astype(np.int32),
        ucols.astype(np.int32),
        inverse.reshape(-1, 16).astype(np.int32),
        diag_index.astype(np.int32),
    )


def serial_pcg_solver(
    offsets,
    columns,
    values,
    diag_index,
    inv_diag,
    b,
    d,
    work,
    result,
    tol,
    max_iter,
    device,
    omega=SSOR_OMEGA,
):
    """``solve(atol, rtol=tol) -> CG steps`` for ``H d = b`` by :func:`pcg_serial` (one thread, SSOR factor
    ``omega`` in (0, 2); 1 is symmetric Gauss-Seidel); ``offsets``, ``columns``, ``values``, ``diag_index``,
    ``inv_diag`` are the Warp arrays of the pattern and the blocks, ``work`` the five (V,) vec3 scratch arrays
    (r, z, p, q, t), ``result`` a (2,) f64 array."""
    r, z, p, q, t = work

    def solve(atol: float, rtol: float = tol) -> int:
        wp.launch(
            pcg_serial,
            1,
            [
                offsets,
                columns,
                values,
                diag_index,
                inv_diag,
                b,
                f64(rtol),
                f64(atol),
                max_iter,
                f64(omega),
                d,
                r,
                z,
                p,
                q,
                t,
                result,
            ],
            device=device,
        )
        return int(result.numpy()[0])

    return solve


def bsr_cg_solver(
    offsets: np.ndarray, columns: np.ndarray, columns_wp, inv_diag, b, d, tol, max_iter, device
):
    """``(values, solve)``: a :mod:`warp.sparse` BSR matrix with the pattern ``offsets``/``columns`` (whose
    ``values`` array the caller fills with the Hessian blocks) and ``solve(atol, rtol=tol) -> CG steps`` for
    ``H d = b`` by :func:`warp.optim.linear.cg` with block-Jacobi (``inv_diag``)."""
    import warp.optim.linear as wpl
    import warp.sparse as wps

    n = len(offsets) - 1
    rows = np.repeat(np.arange(n, dtype=np.int32), np.diff(offsets))
    matrix = wps.bsr_zeros(n, n, block_type=mat33, device=device)
    wps.bsr_set_from_triplets(
        matrix,
        wp.array(rows, dtype=wp.int32, device=device),
        columns_wp,
        wp.zeros(len(columns), dtype=mat33, device=device),
        prune_numerical_zeros=False,
    )
    if not (
        np.array_equal(matrix.offsets.numpy()[: n + 1], offsets)
        and np.array_equal(matrix.columns.numpy()[: len(columns)], columns)
    ):
        raise RuntimeError("warp.sparse reordered the stiffness pattern; block_topology must match it")

    def precondition(x, y, z, alpha, beta):
        wp.launch(apply_block_jacobi, n, [inv_diag, x, y, z, f64(alpha), f64(beta)], device=device)

    jacobi = wpl.LinearOperator((3 * n, 3 * n), mat33, device, precondition)
    state = wpl.cg(matrix, b, d, tol=tol, maxiter=max_iter, M=jacobi, use_cuda_graph=False, run=False)

    def solve(atol: float, rtol: float = tol) -> int:  # the state fixes both tolerances at creation
        if rtol != tol:
            raise ValueError(f"bsr_cg_solver: the relative tolerance is fixed at {tol}, got {rtol}")
        iterations, _, _ = state()
        return int(iterations)

    return matrix.values, solve
