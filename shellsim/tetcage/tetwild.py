"""fTetWild (``pytetwild``) run reproducibly, in a child process in a temporary directory.

One fTetWild run on the same input and settings gives a different mesh each time, for three reasons, each
handled here:

- it shuffles the input triangles before inserting them, with a ``std::mt19937`` seeded by
  ``std::random_device`` (``sort_input_faces`` in fTetWild's ``TriangleInsertion.cpp``), which pytetwild
  neither seeds nor disables. The child points the extension module's PLT slot of
  ``std::random_device::_M_getval`` at a function returning :data:`SEED` (Linux ELF only; elsewhere a
  warning says the runs are not reproducible);
- its ``floatTetWild::Random`` is a function-static ``std::mt19937(42)`` that carries on from one run to the
  next within a process: every run gets a fresh process;
- TBB threads: the child runs on one thread.

The child's working directory is a temporary directory, so fTetWild's ``__tracked_surface.stl`` never lands
in the caller's, and a crash of fTetWild is an error message instead of the end of the caller.
"""

from __future__ import annotations

import ctypes
import logging
import os
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

#: What the patched ``std::random_device`` returns: the seed of fTetWild's triangle insertion order.
SEED = 1
_SYMBOL = b"_ZNSt13random_device9_M_getvalEv"
_SHT_RELA, _PT_LOAD, _PT_GNU_RELRO = 4, 1, 0x6474E552


def _got_slot(path: Path, symbol: bytes) -> tuple[int, int, tuple[int, int] | None] | None:
    """(slot address relative to the load base, lowest PT_LOAD address, RELRO range or None) of the
    relocation of ``symbol`` in a 64-bit little-endian ELF shared object; None when it has none."""
    data = path.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        return None
    phoff, shoff = struct.unpack_from("<QQ", data, 0x20)
    phentsize, phnum, shentsize, shnum = struct.unpack_from("<HHHH", data, 0x36)
    loads, relro = [], None
    for i in range(phnum):
        p_type, _, _, p_vaddr, _, _, p_memsz = struct.unpack_from("<IIQQQQQ", data, phoff + i * phentsize)
        if p_type == _PT_LOAD:
            loads.append(p_vaddr)
        elif p_type == _PT_GNU_RELRO:
            relro = (p_vaddr, p_vaddr + p_memsz)
    # sh_name, sh_type, sh_flags, sh_addr, sh_offset, sh_size, sh_link, sh_info, sh_addralign, sh_entsize
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]
    for sec in sections:
        if sec[1] != _SHT_RELA or not sec[6] < len(sections):
            continue
        symtab = sections[sec[6]]
        strtab = sections[symtab[6]]
        for offset in range(sec[4], sec[4] + sec[5], 24):
            r_offset, r_info = struct.unpack_from("<QQ", data, offset)
            (st_name,) = struct.unpack_from("<I", data, symtab[4] + (r_info >> 32) * 24)
            start = strtab[4] + st_name
            if data[start : data.index(b"\0", start)] == symbol:
                return r_offset, min(loads), relro
    return None


def _load_base(path: Path) -> int | None:
    """Address at which ``path`` is mapped (its file offset 0) in this process, from /proc/self/maps."""
    real = os.path.realpath(path)
    with open("/proc/self/maps") as maps:
        for line in maps:
            fields = line.split()
            if len(fields) >= 6 and fields[5] == real and int(fields[2], 16) == 0:
                return int(fields[0].split("-")[0], 16)
    return None


#: Kept alive for as long as the patched slot points at it.
_seed_function = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_void_p)(lambda _self: SEED)


def seed_random_device(module_path: Path) -> bool:
    """Make ``std::random_device`` return :data:`SEED` in the loaded extension ``module_path``; False when
    this platform or module does not allow it."""
    if not sys.platform.startswith("linux"):
        return False
    found, base = _got_slot(module_path, _SYMBOL), _load_base(module_path)
    if found is None or base is None:
        return False
    offset, lowest, relro = found
    slot = base - lowest + offset
    libc = ctypes.CDLL(None, use_errno=True)
    page = os.sysconf("SC_PAGE_SIZE")
    protected = relro is not None and relro[0] <= offset < relro[1]
    if protected and libc.mprotect(ctypes.c_void_p(slot & ~(page - 1)), page, 3) != 0:  # read | write
        return False
    ctypes.c_void_p.from_address(slot).value = ctypes.cast(_seed_function, ctypes.c_void_p).value
    if protected:
        libc.mprotect(ctypes.c_void_p(slot & ~(page - 1)), page, 1)
    return True


def tetrahedralize(
    vertices: np.ndarray, faces: np.ndarray, edge: float, epsilon: float
) -> tuple[np.ndarray, np.ndarray, bool]:
    """One fTetWild run in a child process: vertices (N, 3), faces (M, 3) of a closed surface, ideal edge
    length (absolute), envelope (relative to the bounding-box diagonal) -> tet vertices (V, 3) float64,
    tets (T, 4) int64 (positive volumes, unreferenced vertices dropped), and whether the run was seeded
    (reproducible). A failure of fTetWild is a ``RuntimeError`` with its last words."""
    with tempfile.TemporaryDirectory(prefix="shellsim-tetwild-") as tmp:
        np.savez(
            Path(tmp) / "in.npz",
            vertices=np.asarray(vertices, np.float64),
            faces=np.asarray(faces, np.int32),
            edge=np.float64(edge),
            epsilon=np.float64(epsilon),
        )
        root = str(Path(__file__).resolve().parent.parent)
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        done = subprocess.run(
            [sys.executable, "-m", "shellsim.tetcage.tetwild", "in.npz", "out.npz"],
            cwd=tmp,
            env=env,
            capture_output=True,
            text=True,
        )
        if done.returncode != 0:
            words = (done.stderr.strip() or done.stdout.strip() or "no output").splitlines()[-1]
            raise RuntimeError(f"fTetWild failed (exit code {done.returncode}): {words}")
        with np.load(Path(tmp) / "out.npz") as out:
            tet_v, tet_t, seeded = out["vertices"], out["tets"], bool(out["seeded"])
    used, tets = np.unique(np.asarray(tet_t, dtype=np.int64), return_inverse=True)
    return np.asarray(tet_v, dtype=np.float64)[used], tets.reshape(-1, 4), seeded


def _child(source: str, target: str) -> None:
    import pytetwild
    from pytetwild import PyfTetWildWrapper

    seeded = seed_random_device(Path(PyfTetWildWrapper.__file__))
    with np.load(source) as data:
        tet_v, tet_t = pytetwild.tetrahedralize(
            data["vertices"],
            data["faces"],
            edge_length_abs=float(data["edge"]),
            epsilon=float(data["epsilon"]),
            vtk_ordering=True,
            quiet=True,
            num_threads=1,
        )
    np.savez(target, vertices=tet_v, tets=tet_t, seeded=np.bool_(seeded))


if __name__ == "__main__":
    _child(*sys.argv[1:3])
