"""Memory a job will need, checked before it starts: a refusal with the estimate and the limit, not OOM.

Each estimate counts the arrays its stage allocates, per unit of what the user asks for (tet, voxel, pixel,
face); the constants below say which arrays. Where a stage is someone else's code (fTetWild, trimesh, the
camera-to-PNG path of the renderer) the constant is the peak resident memory measured per unit
(``resource.getrusage``, between two sizes on a CPU); ``tests/test_memory.py`` measures each again and
checks the estimate lies within a factor of 2. The limit is what the machine can give now:
``MemAvailable`` of ``/proc/meminfo`` (else ``os.sysconf``), lowered to a cgroup's ``memory.max`` headroom,
and the free memory of the GPU (``torch.cuda.mem_get_info``) for work that runs on CUDA.
"""

from __future__ import annotations

import os
from pathlib import Path

from shellsim.errors import SettingError

#: Simulation, per tet [bytes], measured: the growth of the peak resident memory over a frame of the one
#: simulation path (Newton over the bodies with incremental potential contact on the ground: the tets'
#: Hessian blocks assembled into scipy sparse matrices, their SuperLU factorisation with its fill-in, which
#: dominates, ipctk's candidates) between Kuhn boxes of 10k and 48k tets: 11.6 kB (11.5 kB between 25k and
#: 48k). ``tests/test_memory.py`` measures it again.
SIM_PER_TET = 11_600
#: fTetWild (its child process), per tet of the result: its own tet and vertex records, measured
#: (1.05 kB between 35,000 and 283,000 tets of a sphere).
TETWILD_PER_TET = 1050
#: A mesh, per face: trimesh's load (faces int64, vertices and the caches its checks fill), measured.
LOAD_PER_FACE = 430
#: fTetWild, per face of its input: its envelope and AABB tree, measured (between 1,280 and 81,920 faces).
TETWILD_PER_FACE = 500
#: Rendering, per pixel of a frame: the camera's rays, colours and sample counts per chunk and concatenated,
#: the world's static layer of each view (kept for a fixed camera's 4 anti-aliasing views), the sums of the
#: anti-aliasing rays, the frame as float32 and as 8-bit, the PNG encoder's rows: 291 B measured between
#: 512x512 and 1536x1536 (the LEGO drawn in the world, 4 rays, two frames of one view; 2026-12-07; 510 B
#: before the static layer was drawn in chunks and a camera's rows were gathered for every ray).
RENDER_PER_PIXEL = 300
#: Rendering, fixed: the field, the shells' BVH and one chunk of samples through the networks (measured).
RENDER_BASE = 400_000_000
#: Shell extraction, per grid node: f and s (float32), the dilated and eroded copies, the level-set
#: velocity and the float32 grid marching cubes reads (float32 each): 32 B (29 measured).
SHELL_PER_VOXEL = 32
#: Shell extraction: grid nodes sent through the field's networks at a time (``sample_grid``'s chunk) and
#: the bytes of their activations per node (measured).
SHELL_CHUNK, SHELL_PER_SAMPLE = 1 << 18, 650

GB = 1e9


def available_memory(device: str = "cpu") -> int:
    """Bytes the machine can give now to work on ``device``: the GPU's free memory for ``cuda*``, else
    ``MemAvailable`` (or free pages), at most the headroom of the cgroup's ``memory.max``."""
    if str(device).startswith("cuda"):
        import torch

        return int(torch.cuda.mem_get_info(torch.device(device))[0])
    try:
        text = Path("/proc/meminfo").read_text()
        free = next(
            int(line.split()[1]) * 1024 for line in text.splitlines() if line.startswith("MemAvailable:")
        )
    except (OSError, StopIteration, ValueError):
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    try:
        cgroup = Path("/sys/fs/cgroup")
        limit = (cgroup / "memory.max").read_text().strip()
        if limit != "max":
            free = min(free, int(limit) - int((cgroup / "memory.current").read_text()))
    except (OSError, ValueError):
        pass
    return free


def simulation_bytes(n_tets: int) -> int:
    """Peak bytes of simulating a cage of ``n_tets`` tets (:data:`SIM_PER_TET`; its vertices, about a fifth
    as many, are counted in)."""
    return SIM_PER_TET * n_tets


def tetwild_bytes(n_tets: int) -> int:
    """Peak bytes of building a cage of about ``n_tets`` tets: :data:`TETWILD_PER_TET` per tet."""
    return TETWILD_PER_TET * n_tets


def cage_bytes(n_tets: int) -> int:
    """Peak bytes of building a cage of about ``n_tets`` tets (:func:`tetwild_bytes`) and then simulating it
    (:func:`simulation_bytes`): the larger, as they run in turn."""
    return max(tetwild_bytes(n_tets), simulation_bytes(n_tets))


def mesh_bytes(n_faces: int, n_tets: int) -> int:
    """Peak bytes of loading and tetrahedralising a mesh of ``n_faces`` faces into ``n_tets`` tets and
    simulating it: :data:`LOAD_PER_FACE` and :data:`TETWILD_PER_FACE` per face and :func:`cage_bytes`."""
    return (LOAD_PER_FACE + TETWILD_PER_FACE) * n_faces + cage_bytes(n_tets)


def render_bytes(width: int, height: int) -> int:
    """Peak bytes of rendering one frame of ``width`` x ``height``: :data:`RENDER_BASE` and
    :data:`RENDER_PER_PIXEL` per pixel."""
    return RENDER_BASE + RENDER_PER_PIXEL * width * height


def shell_bytes(resolution: int) -> int:
    """Peak bytes of extracting shells on a ``resolution``^3 grid: :data:`SHELL_PER_VOXEL` per node and
    :data:`SHELL_PER_SAMPLE` per node of a chunk."""
    nodes = resolution**3
    return SHELL_PER_VOXEL * nodes + SHELL_PER_SAMPLE * min(nodes, SHELL_CHUNK)


def check_memory(setting: str, needed: int, what: str, purpose: str, device: str = "cpu") -> None:
    """A :class:`SettingError` of ``setting`` when ``needed`` bytes exceed :func:`available_memory`:
    "``what`` needs about N GB ``purpose``; this machine has M GB available"."""
    free = available_memory(device)
    if needed > free:
        where = "this GPU has" if str(device).startswith("cuda") else "this machine has"
        raise SettingError(
            setting, f"{what} needs about {_gb(needed)} {purpose}; {where} {_gb(free)} available"
        )


def _gb(n: int) -> str:
    """Bytes for a person: "850 MB", "2.4 GB", "61 GB"."""
    if n < GB:
        return f"{n / 1e6:.0f} MB"
    return f"{n / GB:.1f} GB" if n < 10 * GB else f"{n / GB:.0f} GB"
