"""Tet meshes, asset directories and cages that tests build by hand (no fTetWild).

- :func:`kuhn_grid`: a box split into cells of 6 positively oriented Kuhn tets, with closed-form tet order.
- :func:`write_asset_dir`: a minimal asset directory (``asset.json``, the two shells, a field file).
- :func:`save_embedded_cage`: a cage of given tets around an asset's shells, embedded and saved.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np


def kuhn_grid(lo, hi, cells):
    """The box ``[lo, hi]`` split into ``cells`` cells per axis, each cell into 6 positively oriented tets.

    lo, hi : (3,) float or a float (the same on every axis)
    cells : int or (3,) int, cells per axis
    returns : vertices ((nx+1)(ny+1)(nz+1), 3) float64, tets (6 nx ny nz, 4) int64 and flip (T,) bool.
        Tet ``6 * cell + p`` (cells in C order) walks from the cell's lowest corner to its highest adding
        the axes in the order of permutation ``p`` (``itertools.permutations`` order); ``flip`` marks the
        tets whose first two vertices were swapped to make them positive.
    """
    cells = [int(n) for n in np.broadcast_to(cells, 3)]
    lo, hi = np.broadcast_to(lo, 3), np.broadcast_to(hi, 3)
    axes = [np.linspace(lo[k], hi[k], cells[k] + 1) for k in range(3)]
    verts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(len(verts)).reshape([n + 1 for n in cells])
    tets = []
    for cell in itertools.product(*(range(n) for n in cells)):
        for perm in itertools.permutations(range(3)):
            corner = list(cell)
            tet = [idx[tuple(corner)]]
            for axis in perm:
                corner[axis] += 1
                tet.append(idx[tuple(corner)])
            tets.append(tet)
    tets = np.array(tets, dtype=np.int64)
    e = verts[tets[:, 1:]] - verts[tets[:, :1]]
    flip = np.einsum("ti,ti->t", e[:, 0], np.cross(e[:, 1], e[:, 2])) < 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    return verts, tets, flip


def write_asset_dir(root: Path, outer, inner, name: str, center=(0, 0, 0), scale=1.0, up=None, field=None):
    """A minimal asset directory at ``root``: ``asset.json``, the shells ``outer`` / ``inner`` (trimesh) as
    PLY and ``field``'s weights (None: a placeholder file that cannot be read as weights).

    ``asset.json`` names the asset ``name`` with normalisation ``center`` / ``scale`` and, unless None, the
    ``up`` axis. Returns ``root``."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    outer.export(root / "shell_outer.ply")
    inner.export(root / "shell_inner.ply")
    if field is None:
        (root / "field.safetensors").write_bytes(b"placeholder")
    else:
        from safetensors.torch import save_file

        save_file({k: v.contiguous() for k, v in field.state_dict().items()}, str(root / "field.safetensors"))
    meta = {
        "format": "shellsim-asset",
        "format_version": 1,
        "name": name,
        "normalisation": {"center": list(center), "scale": scale},
        **({} if up is None else {"up": list(up)}),
        "files": {
            "field": "field.safetensors",
            "shell_outer": "shell_outer.ply",
            "shell_inner": "shell_inner.ply",
        },
        "field": {} if field is None else field.config_dict(),
    }
    (root / "asset.json").write_text(json.dumps(meta))
    return root


def save_embedded_cage(asset, verts, tets):
    """The cage ``verts`` (V, 3), ``tets`` (T, 4) around ``asset``'s shells: both shells embedded in it, saved
    to ``asset.cage_path`` (where ``load_or_build_cage`` finds it). Returns the :class:`Cage`."""
    from shellsim.tetcage.build import Cage, shell_digest
    from shellsim.tetcage.embed import embed_points
    from shellsim.tetcage.store import save_cage

    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    cage = Cage(
        verts,
        tets,
        *embed_points(verts, tets, outer.vertices),
        *embed_points(verts, tets, inner.vertices),
        shell_digest(outer, inner),
    )
    save_cage(asset.cage_path, cage)
    return cage


def save_collision_surface(asset, cage, mesh):
    """``mesh`` (a closed trimesh inside ``cage``) stored as ``asset``'s own collision surface, for assets
    whose field is a placeholder (its zero level set cannot be taken)."""
    from shellsim.tetcage.collision import (
        MAX_FACES,
        OWN_FILE,
        RESOLUTION,
        save_surface,
        surface_key,
        surface_of_mesh,
    )
    from shellsim.tetcage.geometry import cage_digest

    surface = surface_of_mesh(mesh.vertices, mesh.faces, cage.vertices, cage.tets)
    key = surface_key(asset.digest(), cage_digest(cage.vertices, cage.tets), MAX_FACES, RESOLUTION)
    save_surface(asset.root / OWN_FILE, key, surface)


def own_surface(tets, n, friction: float = 0.5):
    """A tet mesh's boundary as its :class:`shellsim.physics.ipc.BodySurface` (weights: the identity on its
    boundary vertices), with the Coulomb coefficient ``friction``."""
    import scipy.sparse as sp

    from shellsim.physics.ipc import BodySurface
    from shellsim.tetcage.geometry import boundary_faces

    faces = boundary_faces(tets)
    used, local = np.unique(faces, return_inverse=True)
    w = sp.csr_matrix((np.ones(len(used)), (np.arange(len(used)), used)), shape=(len(used), n))
    return BodySurface(w, local.reshape(-1, 3), friction)
