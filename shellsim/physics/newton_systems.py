"""The Newton systems ``H d = r`` of a run: ``H`` sparse symmetric positive definite (n, n), one per Newton
iteration, their sparsity patterns mostly alike from one to the next (the cage's blocks, plus the contacts').

Two ways, the faster where it is installed:

- ``"cholesky"``: MKL Pardiso's supernodal sparse Cholesky (``pypardiso``'s binding; two threads for large
  systems, :data:`PARALLEL_UNKNOWNS`), on the upper triangle with METIS ordering. The ordering and symbolic
  analysis are kept while the pattern holds (a contact between bodies changes it), so an iteration costs one
  numeric factorisation and one solve.
- ``"cg"``: SciPy only. Conjugate gradients preconditioned by the exact factorisation (SuperLU,
  minimum-degree ordering of ``A^T + A``, symmetric pivoting) of an earlier ``H``, refactored from the
  current one when CG would need more than :data:`REUSE_ITERATIONS`.

On the 2k- and 8k-tet cubes of ``bench/sim_bench.py`` the first takes 2 and 13 ms an iteration, the second 5.4
and 54 (docs/measurements.md).
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
import weakref

import numpy as np
import scipy.sparse as sp

log = logging.getLogger(__name__)

#: Conjugate-gradient iterations a Newton system may take with an earlier Hessian's factorisation as its
#: preconditioner before the current Hessian is factorised (``"cg"``).
REUSE_ITERATIONS = 25
#: The analysed pattern of :class:`PardisoCholesky` restarts from the current matrix's when it holds more
#: than this many times the current matrix's entries.
UNION_GROWTH = 1.2
#: Systems of fewer unknowns are factorised on one thread. On 2 cores of a quiet machine: a live cage's (some
#: 3,000; the viewer's picture and Warp busy meanwhile) ran at 7.7 / 8.8 live frames a second on two against
#: 8.2 / 9.9 on one; sim_bench's 8k-tet cube (5,184) took 69 against 96 ms a step, a lego_on_bunny system
#: (13,698) factorised in 15 against 26-37 ms (docs/measurements.md).
PARALLEL_UNKNOWNS = 4000
#: The hint when ``pypardiso`` cannot be loaded.
PARDISO_HINT = "pypardiso (MKL) is not installed: Newton systems use SciPy's SuperLU, several times slower"

_hinted = False


def pardiso_solver():
    """A new ``pypardiso.PyPardisoSolver`` for real SPD matrices. Unless ``PYPARDISO_MKL_RT`` names MKL's
    library, pypardiso looks for it by a recursive glob of the environment (a second on a full one), so it is
    named there first: from the ``mkl`` package's file list, else as the first solver found it."""
    import pypardiso

    # MKL's threads on GNU OpenMP (torch's runtime): Intel's own beside it is a second OpenMP runtime in the
    # process, which can hang at exit
    os.environ.setdefault("MKL_THREADING_LAYER", "GNU")
    if "PYPARDISO_MKL_RT" not in os.environ:
        from importlib import metadata

        try:
            files = metadata.files("mkl") or []
        except metadata.PackageNotFoundError:
            files = []
        found = sorted((f for f in files if f.name.startswith("libmkl_rt.so")), key=lambda f: len(f.name))
        if found:
            os.environ["PYPARDISO_MKL_RT"] = str(found[0].locate())
    solver = pypardiso.PyPardisoSolver(mtype=2)
    os.environ.setdefault("PYPARDISO_MKL_RT", solver.libmkl._name)
    return solver


@functools.cache
def pardiso_available() -> bool:
    """Whether ``pypardiso`` and its MKL library load."""
    try:
        pardiso_solver()
    except (ImportError, OSError):
        return False
    return True


def row_pointers(rows: np.ndarray, n: int) -> np.ndarray:
    """(n+1,) int32 the CSR ``indptr`` of entries in rows ``rows`` (nnz,) of an (n, ...) matrix."""
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr.astype(np.int32)


def _keys(upper: sp.csr_matrix) -> np.ndarray:
    """(nnz,) ``row * n + column`` of each entry stored in ``upper`` (n, n), ascending (sorted CSR)."""
    rows = np.repeat(np.arange(upper.shape[0], dtype=np.int64), np.diff(upper.indptr))
    return rows * upper.shape[0] + upper.indices


class PardisoCholesky:
    """Pardiso's Cholesky of SPD matrices given by their upper triangle (CSR, sorted indices) as a ``base``
    part, whose pattern is fixed over many matrices (the cages'), and an ``extra`` part with a few entries
    that come and go (the contacts'). The analysis (METIS ordering, symbolic factorisation) is of the union of
    the patterns seen since the base's last changed, the missing entries stored as zeros: it is redone only
    when an extra entry is new, and the union restarts when it outgrows the matrix by :data:`UNION_GROWTH`."""

    def __init__(self):
        import pypardiso

        self._solver = solver = pardiso_solver()
        solver.set_iparm(1, 1)  # these parameters, not the defaults
        solver.set_iparm(2, 2)  # METIS nested dissection
        self._error = pypardiso.pardiso_wrapper.PyPardisoError
        self._threads = solver.libmkl.MKL_Set_Num_Threads_Local  # this thread's MKL threads; 0: the default
        self._threads.argtypes, self._threads.restype = [ctypes.c_int], ctypes.c_int
        self._base: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # indptr, indices, keys
        self._union: np.ndarray | None = None  # keys of the analysed pattern
        # the analysed pattern's indptr, indices and the base's places in it
        self._pattern: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._upper: sp.csr_matrix | None = None
        self.analyses = 0
        weakref.finalize(self, _release, solver)

    def _call(self, phase: int, upper: sp.csr_matrix, rhs: np.ndarray) -> np.ndarray:
        self._solver.set_phase(phase)
        before = self._threads(0 if upper.shape[0] >= PARALLEL_UNKNOWNS else 1)
        try:
            return self._solver._call_pardiso(upper, rhs)
        finally:
            self._threads(before)

    def factor(self, base: sp.csr_matrix, extra: sp.csr_matrix | None = None) -> bool:
        """Factorises the matrix whose upper triangle is ``base + extra`` (n, n); False when it is not
        positive definite (or Pardiso fails otherwise)."""
        n = base.shape[0]
        if self._base is None or not (
            np.array_equal(self._base[0], base.indptr) and np.array_equal(self._base[1], base.indices)
        ):
            self._base = (base.indptr.copy(), base.indices.copy(), _keys(base))
            self._union = None
        base_keys = self._base[2]
        extra_keys = _keys(extra) if extra is not None and extra.nnz else np.zeros(0, np.int64)
        union = self._union
        if union is not None:
            places = np.minimum(np.searchsorted(union, extra_keys), len(union) - 1)
            if not np.array_equal(union[places], extra_keys):  # a new entry: the union grows
                union = np.union1d(union, extra_keys)
                if len(union) > UNION_GROWTH * (len(base_keys) + len(extra_keys)):
                    union = None
        if union is None:
            union = np.union1d(base_keys, extra_keys)
        if union is not self._union:
            places = np.searchsorted(union, extra_keys)
            rows, columns = np.divmod(union, n)
            self._pattern = (
                row_pointers(rows, n),
                columns.astype(np.int32),
                np.searchsorted(union, base_keys),
            )
        data = np.zeros(len(union))
        data[self._pattern[2]] = base.data
        if len(extra_keys):
            data[places] += extra.data
        upper = sp.csr_matrix((data, self._pattern[1], self._pattern[0]), shape=(n, n))
        zero = np.zeros(n)
        try:
            if union is not self._union:
                # METIS's ordering of the base's first pattern serves the unions that grow from it
                # (Pardiso then skips the ordering, the costlier half of an analysis)
                reorder = self._union is None or self._solver.perm.shape != (n,)
                if reorder:
                    self._solver.perm = np.zeros(n, np.int32)
                self._solver.set_iparm(5, 2 if reorder else 1)  # return the ordering, or use it
                self._call(11, upper, zero)
                self._union = union
                self.analyses += 1
            self._call(22, upper, zero)
        except self._error:
            self._union = self._upper = None
            return False
        self._upper = upper
        return True

    @property
    def factored(self) -> bool:
        """Whether a factorisation is held."""
        return self._upper is not None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """(n,) the solution for ``rhs`` (n,) with the last factorisation."""
        return self._call(33, self._upper, np.ascontiguousarray(rhs, dtype=np.float64).ravel())


def _release(solver) -> None:
    """Frees Pardiso's memory of ``solver``."""
    solver.set_phase(-1)
    try:
        solver._call_pardiso(sp.csr_matrix((0, 0)), np.zeros(0))
    except Exception:  # noqa: BLE001 - at interpreter exit the library may be gone; nothing is left to free
        pass


class NewtonSystems:
    """Solves a run's Newton systems by ``method`` (module docstring): ``"auto"`` (Cholesky where
    ``pypardiso`` loads, else CG), ``"cholesky"`` or ``"cg"``. ``factorisations`` counts the numeric
    factorisations of either."""

    def __init__(self, method: str = "auto", rtol: float = 1e-4):
        global _hinted
        if method not in ("auto", "cholesky", "cg"):
            raise ValueError(f"unknown linear solver {method!r}: auto, cholesky or cg")
        if method == "auto":
            method = "cholesky" if pardiso_available() else "cg"
            if method == "cg" and not _hinted:
                log.info(PARDISO_HINT)
                _hinted = True
        self.method = method
        #: the part of the symmetric matrices :meth:`solve` takes: "upper" (its upper triangle, CSR with
        #: sorted indices) for Cholesky, "full" for CG
        self.triangle = "upper" if method == "cholesky" else "full"
        self.rtol = rtol
        self._cholesky = PardisoCholesky() if method == "cholesky" else None
        self._factor = None  # "cg": the SuperLU factorisation serving as preconditioner
        self.factorisations = 0

    def solve(self, matrix: sp.spmatrix, rhs: np.ndarray, extra: sp.spmatrix | None = None) -> np.ndarray:
        """``d`` (n,) of the symmetric matrix ``matrix + extra`` (n, n; each given by its :attr:`triangle`;
        ``extra`` a few entries whose pattern changes, the contacts') and ``rhs`` (n,) (``"cg"``:
        ``|H d - r| <= rtol |r|``); all nan where it cannot be factorised. A matrix Cholesky refuses (not
        positive definite in floating point) goes the ``"cg"`` way."""
        if self._cholesky is None:
            full = matrix if extra is None else matrix + extra
            return self._preconditioned_cg(full.tocsc(), rhs)
        upper = sp.csr_matrix(matrix)
        upper.sort_indices()
        if extra is not None:
            extra = sp.csr_matrix(extra)
            extra.sort_indices()
        self.factorisations += 1
        if self._cholesky.factor(upper, extra):
            return self._cholesky.solve(rhs)
        if extra is not None:
            upper = upper + extra
        full = upper + sp.triu(upper, k=1).T
        return self._preconditioned_cg(full.tocsc(), rhs)

    def resolve(self, rhs: np.ndarray) -> np.ndarray | None:
        """(n,) the solution for ``rhs`` (n,) with the last factorisation as it stands (an earlier matrix's:
        an approximation), None when there is none."""
        if self._cholesky is not None and self._cholesky.factored:
            return self._cholesky.solve(rhs)
        if self._factor is not None and self._factor.shape[0] == len(rhs):
            return self._factor.solve(rhs)
        return None

    def _preconditioned_cg(self, matrix: sp.csc_matrix, rhs: np.ndarray) -> np.ndarray:
        from scipy.sparse.linalg import LinearOperator, cg, splu

        n = len(rhs)
        if self._factor is not None and self._factor.shape == matrix.shape:
            preconditioner = LinearOperator((n, n), matvec=self._factor.solve)
            d, info = cg(matrix, rhs, rtol=self.rtol, maxiter=REUSE_ITERATIONS, M=preconditioner)
            if info == 0:
                return d
        try:
            self._factor = splu(matrix, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
        except RuntimeError:
            self._factor = None
            return np.full(n, np.nan)
        self.factorisations += 1
        return self._factor.solve(rhs)
