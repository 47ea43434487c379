"""The stable Neo-Hookean tetrahedral element in Warp: energy density, stress, the analytic PSD Hessian
(closed-form eigenvalues; shift or SVD eigen-projection) and :func:`tet_terms`, the kernel that accumulates
each tet's energy, forces and 3x3 Hessian blocks (with Kelvin-Voigt damping) for
:mod:`shellsim.physics.body`, and the blocks' sparsity (:func:`block_topology`); :func:`max_principal_stretch`
for the frame driver's check; plus NumPy/host helpers (:func:`snh_energy_reference`, :func:`elastic_energy`)
used by tests and benchmarks. The model (with its volume barrier below det F = ``BARRIER_J``) and its
definiteness fix are described in :mod:`shellsim.physics.body`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from shellsim.physics.materials import Material
from shellsim.tetcage.geometry import tet_volumes

wp.set_module_options({"enable_backward": False})  # no autodiff here; halves compile time

vec3 = wp.vec3d
mat33 = wp.mat33d
f64 = wp.float64
vec9 = wp.types.vector(length=9, dtype=wp.float64)
mat99 = wp.types.matrix(shape=(9, 9), dtype=wp.float64)


SHIFT_LIMIT = 0.1  # largest Hessian shift (in units of mu) used instead of the eigen-projection
ENERGY, FORCE, HESSIAN = (wp.constant(k) for k in (0, 1, 2))  # what an evaluation computes


BARRIER_J = 0.5  # volume ratio below which the volume barrier acts
BARRIER_STIFFNESS = 10.0  # its stiffness, in units of lam


@wp.func
def volume_terms(J: f64, lam: f64) -> vec3:
    """(phi, phi', phi'') of the volumetric energy phi(J) = lam/2 (J - 1)^2 + b(J), with the barrier
    b(J) = -kb lam (J - Jb)^2 log(J / Jb) for J < Jb, kb = BARRIER_STIFFNESS (C2 at Jb, infinite at J = 0)."""
    d = J - f64(1.0)
    out = vec3(f64(0.5) * lam * d * d, lam * d, lam)
    jb = f64(BARRIER_J)
    if J < jb:
        if J <= f64(0.0):
            return vec3(f64(1.0e300), f64(0.0), f64(0.0))
        e = J - jb
        g = wp.log(J / jb)
        db = -(f64(2.0) * e * g + e * e / J)
        ddb = -(f64(2.0) * g + f64(4.0) * e / J - e * e / (J * J))
        out += f64(BARRIER_STIFFNESS) * lam * vec3(-e * e * g, db, ddb)
    return out


@wp.func
def snh_energy(F: mat33, mu: f64, lam: f64) -> f64:
    """Psi(F) = mu/2 (|F|^2 - 3) - mu (J - 1) + phi(J) (:func:`volume_terms`)."""
    J = wp.determinant(F)
    return f64(0.5) * mu * (wp.ddot(F, F) - f64(3.0)) - mu * (J - f64(1.0)) + volume_terms(J, lam)[0]


@wp.func
def det_gradient(F: mat33) -> mat33:
    """dJ/dF = cofactor of F: columns f1 x f2, f2 x f0, f0 x f1."""
    Ft = wp.transpose(F)
    return wp.matrix_from_cols(wp.cross(Ft[1], Ft[2]), wp.cross(Ft[2], Ft[0]), wp.cross(Ft[0], Ft[1]))


@wp.func
def snh_stress(F: mat33, mu: f64, lam: f64) -> mat33:
    """First Piola-Kirchhoff stress P = dPsi/dF = mu F + (phi'(J) - mu) dJ/dF."""
    J = wp.determinant(F)
    return mu * F + (volume_terms(J, lam)[1] - mu) * det_gradient(F)


@wp.func
def flat(M: mat33) -> vec9:
    """vec(M), row-major: index 3 i + j holds M[i, j]."""
    return vec9(M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2], M[2, 0], M[2, 1], M[2, 2])


@wp.func
def scaling_modes(s: vec3, mu: f64, lam: f64, k: f64) -> mat33:
    """The 3x3 matrix whose eigenpairs are the scaling modes of d2Psi/dF2 at singular values ``s``
    (Smith et al. 2019): ``mu I + lam c c^T + k [[0, s2, s1], [s2, 0, s0], [s1, s0, 0]]``,
    ``c = (s1 s2, s0 s2, s0 s1)``; pass ``lam = phi''(J)``, ``k = phi'(J) - mu`` (:func:`volume_terms`)."""
    c = vec3(s[1] * s[2], s[0] * s[2], s[0] * s[1])
    zero = f64(0.0)
    return (
        mu * wp.identity(n=3, dtype=f64)
        + lam * wp.outer(c, c)
        + k * mat33(zero, s[2], s[1], s[2], zero, s[0], s[1], s[0], zero)
    )


@wp.func
def snh_hessian_psd(F: mat33, mu: f64, lam: f64) -> mat99:
    """d2Psi/dF2 (row-major vec(F)) with negative eigenvalues clamped, from the analytic eigensystem."""
    U = mat33()
    s = vec3()
    V = mat33()
    wp.svd3(F, U, s, V)
    if wp.determinant(U) * wp.determinant(V) < f64(0.0):
        U = U * wp.diag(vec3(f64(1.0), f64(1.0), f64(-1.0)))
        s[2] = -s[2]
    Ut = wp.transpose(U)
    Vt = wp.transpose(V)
    phi = volume_terms(s[0] * s[1] * s[2], lam)
    k = phi[1] - mu
    r = f64(0.7071067811865476)
    H = mat99()
    for m in range(3):
        i = wp.where(m == 0, 1, 0)
        j = wp.where(m == 2, 1, 2)
        a = wp.outer(Ut[j], Vt[i])
        b = wp.outer(Ut[i], Vt[j])
        twist = flat(r * (a - b))
        flip = flat(r * (a + b))
        H += wp.max(mu + k * s[m], f64(0.0)) * wp.outer(twist, twist)
        H += wp.max(mu - k * s[m], f64(0.0)) * wp.outer(flip, flip)
    A = scaling_modes(s, mu, phi[2], k)
    Q = mat33()
    d = vec3()
    wp.eig3(A, Q, d)
    Qt = wp.transpose(Q)
    for m in range(3):
        q = Qt[m]
        mode = flat(
            q[0] * wp.outer(Ut[0], Vt[0]) + q[1] * wp.outer(Ut[1], Vt[1]) + q[2] * wp.outer(Ut[2], Vt[2])
        )
        H += wp.max(d[m], f64(0.0)) * wp.outer(mode, mode)
    return H


@wp.func
def sym_eigenvalues(A: mat33) -> vec3:
    """Eigenvalues of a symmetric 3x3 matrix, descending, in closed form (trigonometric method)."""
    q = wp.trace(A) / f64(3.0)
    off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
    diag = (A[0, 0] - q) * (A[0, 0] - q) + (A[1, 1] - q) * (A[1, 1] - q) + (A[2, 2] - q) * (A[2, 2] - q)
    p = wp.sqrt((diag + f64(2.0) * off) / f64(6.0))
    if p <= f64(1.0e-300):
        return vec3(q, q, q)
    B = (A - q * wp.identity(n=3, dtype=f64)) / p
    r = wp.clamp(wp.determinant(B) / f64(2.0), f64(-1.0), f64(1.0))
    phi = wp.acos(r) / f64(3.0)
    e0 = q + f64(2.0) * p * wp.cos(phi)
    e2 = q + f64(2.0) * p * wp.cos(phi + f64(2.0943951023931957))
    return vec3(e0, f64(3.0) * q - e0 - e2, e2)


@wp.func
def positive_definite(A: mat33) -> bool:
    """Whether a symmetric 3x3 matrix is positive definite (Sylvester: its leading minors are positive)."""
    return (
        A[0, 0] > f64(0.0)
        and A[0, 0] * A[1, 1] - A[0, 1] * A[0, 1] > f64(0.0)
        and wp.determinant(A) > f64(0.0)
    )


@wp.func
def snh_min_eigenvalue(F: mat33, mu: f64, lam: f64) -> f64:
    """Smallest eigenvalue of d2Psi/dF2 from the singular values alone (Smith et al. 2019 eigenvalues)."""
    e = sym_eigenvalues(wp.transpose(F) * F)
    J = wp.determinant(F)
    s = vec3(
        wp.sqrt(wp.max(e[0], f64(0.0))), wp.sqrt(wp.max(e[1], f64(0.0))), wp.sqrt(wp.max(e[2], f64(0.0)))
    )
    if J < f64(0.0):
        s[2] = -s[2]
    phi = volume_terms(J, lam)
    k = phi[1] - mu
    twist_flip = mu - wp.abs(k) * s[0]
    A = scaling_modes(s, mu, phi[2], k)
    if positive_definite(A - twist_flip * wp.identity(n=3, dtype=f64)):
        return twist_flip  # every scaling eigenvalue lies above it: no eigen-solve (the common case)
    return wp.min(twist_flip, sym_eigenvalues(A)[2])


@wp.func
def contract(H: mat99, ga: vec3, gb: vec3) -> mat33:
    """3x3 block of B^T H B for vertices a, b: out[i, k] = sum_jl H[3i+j, 3k+l] ga[j] gb[l]."""
    out = mat33()
    for i in range(3):
        for k in range(3):
            acc = f64(0.0)
            for j in range(3):
                for l in range(3):
                    acc += H[3 * i + j, 3 * k + l] * ga[j] * gb[l]
            out[i, k] = acc
    return out


mat43 = wp.types.matrix(shape=(4, 3), dtype=f64)


@wp.func
def shape_gradients(dm_inv: mat33) -> mat43:
    """Rows g_a (4, 3): the rest-space gradients of the linear shape functions, F = sum_a x_a g_a^T."""
    g = -(dm_inv[0] + dm_inv[1] + dm_inv[2])
    return wp.matrix_from_rows(g, dm_inv[0], dm_inv[1], dm_inv[2])


@wp.func
def deformation_gradient(x: wp.array(dtype=vec3), tet: wp.array2d(dtype=wp.int32), t: int, dm_inv: mat33):
    x0 = x[tet[t, 0]]
    Ds = wp.matrix_from_cols(x[tet[t, 1]] - x0, x[tet[t, 2]] - x0, x[tet[t, 3]] - x0)
    return Ds * dm_inv


@wp.func
def damping_terms(F: mat33, Fp: mat33, damp_mu: f64, damp_lam: f64):
    """Kelvin-Voigt damping per unit volume (``Fp`` = F at the substep start): D(A) and dD/dF = Fp S,
    ``A = Fp^T (F - Fp)``, ``S = 2 damp_mu sym A + damp_lam tr(A) I``; zeros without damping."""
    if damp_mu == f64(0.0) and damp_lam == f64(0.0):
        return f64(0.0), mat33()
    A = wp.transpose(Fp) * (F - Fp)
    symA = f64(0.5) * (A + wp.transpose(A))
    trA = wp.trace(A)
    S = f64(2.0) * damp_mu * symA + damp_lam * trA * wp.identity(n=3, dtype=f64)
    return damp_mu * wp.ddot(symA, symA) + f64(0.5) * damp_lam * trA * trA, Fp * S


@wp.func
def damping_block(Fp: mat33, damp_mu: f64, damp_lam: f64, ga: vec3, gb: vec3) -> mat33:
    """Block (a, b) of the Kelvin-Voigt damping Hessian per unit volume (``Fp`` = F at the substep start)."""
    if damp_mu == f64(0.0) and damp_lam == f64(0.0):
        return mat33()
    Ky = damp_mu * (wp.dot(ga, gb) * wp.identity(n=3, dtype=f64) + wp.outer(gb, ga)) + damp_lam * wp.outer(
        ga, gb
    )
    return Fp * Ky * wp.transpose(Fp)


@wp.func
def add_block(
    values: wp.array(dtype=mat33),
    block_index: wp.array2d(dtype=wp.int32),
    t: int,
    a: int,
    b: int,
    block: mat33,
):
    """Add the Hessian block (a, b) of tet ``t`` and, for a != b, its transpose, block (b, a)."""
    wp.atomic_add(values, block_index[t, 4 * a + b], block)
    if b != a:
        wp.atomic_add(values, block_index[t, 4 * b + a], wp.transpose(block))


@wp.func
def projected_blocks(
    F: mat33,
    Fp: mat33,
    G: mat43,
    vol: f64,
    mu: f64,
    lam: f64,
    damp_mu: f64,
    damp_lam: f64,
    pinned: wp.array(dtype=wp.int32),
    tets: wp.array2d(dtype=wp.int32),
    block_index: wp.array2d(dtype=wp.int32),
    t: int,
    values: wp.array(dtype=mat33),
):
    """Add tet ``t``'s Hessian blocks from the eigen-projected d2Psi/dF2 (:func:`snh_hessian_psd`)."""
    H = snh_hessian_psd(F, mu, lam)
    for a in range(4):
        if pinned[tets[t, a]] == 0:
            for b in range(4):
                if b >= a and pinned[tets[t, b]] == 0:
                    block = contract(H, G[a], G[b]) + damping_block(Fp, damp_mu, damp_lam, G[a], G[b])
                    add_block(values, block_index, t, a, b, vol * block)


@wp.func
def add_hessian_blocks(
    F: mat33,
    Fp: mat33,
    G: mat43,
    vol: f64,
    mu: f64,
    lam: f64,
    damp_mu: f64,
    damp_lam: f64,
    shift_limit: f64,
    pinned: wp.array(dtype=wp.int32),
    tets: wp.array2d(dtype=wp.int32),
    block_index: wp.array2d(dtype=wp.int32),
    t: int,
    values: wp.array(dtype=mat33),
):
    """Add tet ``t``'s Hessian blocks ``V g_a^T H g_b`` (+ damping blocks) of its free vertices (10 computed,
    6 their transposes). Definiteness: where the smallest eigenvalue of d2Psi/dF2 is >= -shift_limit mu,
    the exact blocks plus a shift of (-eigenvalue) mu-like identity (PSD, cheap); beyond, the
    eigen-projected Hessian (SVD)."""
    shift = wp.max(-snh_min_eigenvalue(F, mu, lam), f64(0.0))
    if shift > shift_limit * mu:
        projected_blocks(F, Fp, G, vol, mu, lam, damp_mu, damp_lam, pinned, tets, block_index, t, values)
        return
    # exact block d2Psi/dx_a dx_b = mu (g_a.g_b) I + phi'' (cof g_a)(cof g_b)^T + k d2J/dx_a dx_b,
    # k = phi' - mu, d2J/dx_a dx_b [i, k] = eps_ikm (F (g_a x g_b))_m
    phi = volume_terms(wp.determinant(F), lam)
    k = phi[1] - mu
    C = G * wp.transpose(det_gradient(F))  # rows cof g_a
    for a in range(4):
        if pinned[tets[t, a]] == 0:
            for b in range(4):
                if b >= a and pinned[tets[t, b]] == 0:
                    ga = G[a]
                    gb = G[b]
                    block = (
                        (mu + shift) * wp.dot(ga, gb) * wp.identity(n=3, dtype=f64)
                        + phi[2] * wp.outer(C[a], C[b])
                        - k * wp.skew(F * wp.cross(ga, gb))
                    )
                    block += damping_block(Fp, damp_mu, damp_lam, ga, gb)
                    add_block(values, block_index, t, a, b, vol * block)


@wp.kernel
def tet_terms(
    x: wp.array(dtype=vec3),
    tets: wp.array2d(dtype=wp.int32),
    dm_inv: wp.array(dtype=mat33),
    rest_volume: wp.array(dtype=f64),
    f_prev: wp.array(dtype=mat33),
    mu: f64,
    lam: f64,
    damp_mu: f64,
    damp_lam: f64,
    shift_limit: f64,
    pinned: wp.array(dtype=wp.int32),
    block_index: wp.array2d(dtype=wp.int32),
    order: int,
    energy: wp.array(dtype=f64),
    min_det: wp.array(dtype=f64),
    force: wp.array(dtype=vec3),
    values: wp.array(dtype=mat33),
):
    """Tet ``t``: for ``order`` ENERGY and FORCE, V (Psi(F) + D(A)) (``damp_* = beta/h * Lamé``) and min
    det F, for FORCE also the forces ``-V P g_a`` of its free vertices; for HESSIAN only its Hessian blocks
    (:func:`add_hessian_blocks`)."""
    t = wp.tid()
    Dinv = dm_inv[t]
    F = deformation_gradient(x, tets, t, Dinv)
    vol = rest_volume[t]
    Fp = f_prev[t]
    G = shape_gradients(Dinv)
    if order == HESSIAN:
        add_hessian_blocks(
            F, Fp, G, vol, mu, lam, damp_mu, damp_lam, shift_limit, pinned, tets, block_index, t, values
        )
        return
    damp_energy, damp_stress = damping_terms(F, Fp, damp_mu, damp_lam)
    wp.atomic_add(energy, 0, vol * (snh_energy(F, mu, lam) + damp_energy))
    wp.atomic_min(min_det, 0, wp.determinant(F))
    if order == ENERGY:
        return
    P = vol * (snh_stress(F, mu, lam) + damp_stress)
    for a in range(4):
        ia = tets[t, a]
        if pinned[ia] == 0:
            wp.atomic_sub(force, ia, P * G[a])


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


@wp.kernel
def max_principal_stretch(
    x: wp.array(dtype=vec3),
    tets: wp.array2d(dtype=wp.int32),
    dm_inv: wp.array(dtype=mat33),
    out: wp.array(dtype=f64),
):
    """``out[0] = max(out[0], s0)`` over the tets: ``s0`` the largest singular value of ``F = Ds Dm^-1``, the
    square root of the largest eigenvalue of ``F^T F`` (:func:`sym_eigenvalues`): how many times its rest
    length the most stretched direction of the tet has become."""
    t = wp.tid()
    F = deformation_gradient(x, tets, t, dm_inv[t])
    wp.atomic_max(out, 0, wp.sqrt(wp.max(sym_eigenvalues(wp.transpose(F) * F)[0], f64(0.0))))


def snh_energy_reference(F: np.ndarray, mu: float, lam: float) -> np.ndarray:
    """NumPy twin of the stable Neo-Hookean energy density: F (..., 3, 3) -> Psi (...)."""
    J = np.linalg.det(F)
    e = np.minimum(J - BARRIER_J, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log = np.log(np.minimum(J, BARRIER_J) / BARRIER_J)
        barrier = np.where(J > 0, -BARRIER_STIFFNESS * lam * e * e * log, np.inf)
    return (
        0.5 * mu * (np.sum(F * F, axis=(-2, -1)) - 3.0)
        - mu * (J - 1.0)
        + 0.5 * lam * (J - 1.0) ** 2
        + barrier
    )


def elastic_energy(
    rest_vertices, tets, positions, material: Material, device=None, shift_limit: float = SHIFT_LIMIT
):
    """Stable Neo-Hookean energy of a tet mesh, its gradient and its definiteness-fixed Hessian.

    rest_vertices, positions : (V, 3) [m]; tets : (T, 4). Returns ``(energy [J], gradient (V, 3) [N],
    hessian (3V, 3V) scipy.sparse.bsr_matrix [N/m])``. ``shift_limit`` (in units of mu) chooses per tet
    between the shifted exact Hessian and the eigen-projected one; 0 projects every tet.
    """
    import scipy.sparse

    rest = np.asarray(rest_vertices, np.float64)
    tets = np.asarray(tets)
    x = rest[tets]
    dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
    offsets, columns, block_index, _ = block_topology(tets, len(rest))
    n = len(rest)
    dev = wp.get_device(device)
    scalars = wp.array([0.0, 1.0e300], dtype=f64, device=dev)
    force = wp.zeros(n, dtype=vec3, device=dev)
    values = wp.zeros(len(columns), dtype=mat33, device=dev)
    args = [
        wp.array(positions, dtype=vec3, device=dev),
        wp.array(tets.astype(np.int32), dtype=wp.int32, device=dev),
        wp.array(np.linalg.inv(dm), dtype=mat33, device=dev),
        wp.array(tet_volumes(rest, tets), dtype=f64, device=dev),
        wp.array(np.broadcast_to(np.eye(3), (len(tets), 3, 3)), dtype=mat33, device=dev),
        material.mu,
        material.lam + material.mu,
        0.0,
        0.0,
        shift_limit,
        wp.zeros(n, dtype=wp.int32, device=dev),
        wp.array(block_index, dtype=wp.int32, device=dev),
    ]
    for order in (FORCE, HESSIAN):
        wp.launch(tet_terms, len(tets), [*args, order, scalars[0:1], scalars[1:2], force, values], device=dev)
    hessian = scipy.sparse.bsr_matrix((values.numpy(), columns, offsets), shape=(3 * n, 3 * n))
    return float(scalars.numpy()[0]), -force.numpy(), hessian
