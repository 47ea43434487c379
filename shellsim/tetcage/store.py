"""Where cages are kept: the cage file (``cage.npz``), an asset's own cage and the user cache.

A cage file holds the rest cage (vertices (V, 3) float64, tets (T, 4) int64), the embedding of the shells'
vertices (optional), the :func:`~shellsim.tetcage.build.shell_digest` of the shells it was built for and its
:class:`~shellsim.tetcage.build.CageConfig`. :func:`load_or_build_cage` returns an asset's own cage when it
fits, else a cached one keyed by the shells and the settings, else builds one
(:func:`shellsim.tetcage.build.build_cage`) and caches it; :func:`cage_for_motion` finds the cage a motion was
made with.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np

from neural.errors import InputError
from shellsim.io.npz import load_npz, save_npz
from shellsim.io.outputs import check_writable_file, output_lock
from shellsim.tetcage import build
from shellsim.tetcage.build import Cage, CageConfig, check_tet_mesh, shell_digest
from shellsim.tetcage.embed import BARY_TOL, check_embedding, embed_points, interpolate, outside_distance
from shellsim.tetcage.geometry import check_tets, tet_quality, tet_volumes

FORMAT = "shellsim-cage"


FORMAT_VERSION = 1


EMBEDDING_KEYS = ("outer_tet", "outer_bary", "inner_tet", "inner_bary")

logger = logging.getLogger(__name__)


def cage_summary(cage: Cage) -> dict:
    """Facts about a cage: sizes, volume, worst tet quality, and how many shell vertices lie outside it
    (embedded with extrapolated coordinates) and how far."""
    quality = tet_quality(cage.vertices, cage.tets)
    outside = {}
    for name in ("outer", "inner"):
        tet_index, bary = getattr(cage, f"{name}_tet"), getattr(cage, f"{name}_bary")
        out = np.nonzero(bary.min(axis=1, initial=0.0) < -BARY_TOL)[0]
        points = interpolate(cage.vertices, cage.tets, tet_index[out], bary[out])
        dist = outside_distance(cage.vertices, cage.tets, points)
        outside[name] = (len(tet_index), len(out), float(dist.max(initial=0.0)))
    return {
        "vertices": len(cage.vertices),
        "tets": len(cage.tets),
        "volume": float(tet_volumes(cage.vertices, cage.tets).sum()),
        "min_quality": float(quality.min()),
        "median_quality": float(np.median(quality)),
        "outer_vertices": outside["outer"][0],
        "inner_vertices": outside["inner"][0],
        "outside": outside["outer"][1] + outside["inner"][1],
        "max_outside_distance": max(outside["outer"][2], outside["inner"][2]),
    }


def save_cage(path: str | os.PathLike, cage: Cage, embedding: bool = True) -> None:
    """Write ``cage`` to ``path`` (npz, no pickle) atomically: temporary file + rename; the embedding of the
    shells only if ``embedding``."""
    arrays = {}
    if embedding:
        arrays = {
            "outer_tet": np.asarray(cage.outer_tet, np.int64),
            "outer_bary": np.asarray(cage.outer_bary, np.float64),
            "inner_tet": np.asarray(cage.inner_tet, np.int64),
            "inner_bary": np.asarray(cage.inner_bary, np.float64),
        }
    save_npz(
        path,
        format=np.array(FORMAT),
        format_version=np.array(FORMAT_VERSION),
        vertices=np.asarray(cage.vertices, np.float64),
        tets=np.asarray(cage.tets, np.int64),
        shell_digest=np.array(cage.shell_digest),
        config=np.array(json.dumps(dataclasses.asdict(cage.config))),
        **arrays,
    )


def load_cage(path: str | os.PathLike, shells=None) -> Cage:
    """Read and validate a cage file; any problem is an :class:`InputError` naming the file. A file without
    the embedding needs ``shells`` (outer, inner ``trimesh.Trimesh``) to embed them again."""
    path = Path(path)
    keys = ("format", "format_version", "vertices", "tets", "shell_digest", "config")
    arrays = load_npz(path, keys, "cage", optional=EMBEDDING_KEYS)
    if (
        str(arrays["format"]) != FORMAT
        or arrays["format_version"].shape != ()
        or int(arrays["format_version"]) != FORMAT_VERSION
    ):
        raise InputError(f"{path}: not a {FORMAT} file of format version {FORMAT_VERSION}")
    try:
        config = CageConfig(**json.loads(str(arrays["config"])))
    except (json.JSONDecodeError, TypeError, ValueError) as err:
        raise InputError(f"{path}: invalid config ({err})") from None
    vertices, tets = arrays["vertices"], arrays["tets"]
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.issubdtype(vertices.dtype, np.floating):
        raise InputError(f"{path}: vertices must be (V, 3) floats, got {vertices.shape} {vertices.dtype}")
    try:
        tets = check_tets(tets, len(vertices), allow_empty=True)
    except ValueError as err:
        raise InputError(f"{path}: {err}") from None
    vertices = vertices.astype(np.float64)
    check_tet_mesh(vertices, tets, str(path))
    stored = [k for k in EMBEDDING_KEYS if k in arrays]
    if stored and len(stored) < len(EMBEDDING_KEYS):
        missing = sorted(set(EMBEDDING_KEYS) - set(stored))
        raise InputError(f"{path}: not a cage file, missing {', '.join(missing)}")
    if not stored:
        if shells is None:
            raise InputError(
                f"{path}: the cage file holds no embedding of the shells; load it with its asset"
            )
        for name, mesh in zip(("outer", "inner"), shells, strict=True):
            arrays[f"{name}_tet"], arrays[f"{name}_bary"] = embed_points(vertices, tets, mesh.vertices)
    for name in ("outer", "inner"):
        names = (f"{name}_tet", f"{name}_bary")
        try:
            _, bary = check_embedding(arrays[names[0]], arrays[names[1]], len(tets), names)
        except ValueError as err:
            raise InputError(f"{path}: {err}") from None
        if not np.isfinite(bary).all() or not np.allclose(bary.sum(axis=1), 1.0, rtol=0, atol=1e-6):
            raise InputError(f"{path}: {name}_bary rows must be finite and sum to 1")
    return Cage(
        vertices,
        tets.astype(np.int64),
        arrays["outer_tet"].astype(np.int64),
        arrays["outer_bary"].astype(np.float64),
        arrays["inner_tet"].astype(np.int64),
        arrays["inner_bary"].astype(np.float64),
        str(arrays["shell_digest"]),
        config,
        str(path),
    )


def cache_dir() -> Path:
    """Where cages that may not live beside their asset are kept: ``$SHELLSIM_CACHE`` (``shellsim
    --cache-dir``), else ``$XDG_CACHE_HOME/shellsim``, else ``~/.cache/shellsim``."""
    env = os.environ.get("SHELLSIM_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "shellsim"


def cached_cage_path(digest: str, config: CageConfig) -> Path:
    """The cache's file for the cage of the shells with :func:`shell_digest` ``digest`` built with ``config``:
    ``CACHE/cages/<shells>-<settings>.npz``, both parts digests, so no two cages share a file."""
    settings = hashlib.sha256(json.dumps(dataclasses.asdict(config), sort_keys=True).encode()).hexdigest()
    return cache_dir() / "cages" / f"{digest[:16]}-{settings[:16]}.npz"


def _read(path: Path, shells, digest: str) -> Cage | None:
    """The cage at ``path`` if it is readable and made from these shells, else None (logged)."""
    if not path.is_file():
        return None
    try:
        cage = load_cage(path, shells)
    except InputError as err:
        logger.warning("not using %s: %s", path, err)
        return None
    if cage.shell_digest != digest:
        logger.info("not using %s: made from other shells", path)
        return None
    return cage


def load_or_build_cage(asset, config: CageConfig | None = None, rebuild: bool = False) -> Cage:
    """The cage of an asset with ``config`` (None: the asset's own cage whatever its settings, else the
    defaults; with ``rebuild``, the own cage's settings), loaded when one was made from these shells, else
    built and saved (without the embedding, which is computed again on loading).

    Where cages live: the asset's ``cage.npz`` holds its own cage (shipped with ``assets/lego``). A cage
    with other settings, any cage of a shipped asset that it does not ship, and a ``rebuild`` next to a
    good own cage go to :func:`cached_cage_path`: a shipped asset is never written to, and a cage that
    motions were made with is never replaced by another.
    """
    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    digest = shell_digest(outer, inner)
    own = _read(asset.cage_path, (outer, inner), digest)
    if own is not None and not rebuild and (config is None or own.config == config):
        return own
    config = config or (own.config if own is not None else CageConfig())
    cached = cached_cage_path(digest, config)
    if not rebuild:
        cage = _read(cached, (outer, inner), digest)
        if cage is not None:
            return cage
    path = cached if asset.shipped or own is not None else asset.cage_path
    check_writable_file(path)  # before the build, not after it
    with output_lock(path):  # one build per cage file at a time
        cage = build.build_cage(outer, inner, config, what=str(asset.file("shell_outer")))
        path.parent.mkdir(parents=True, exist_ok=True)
        save_cage(path, cage, embedding=False)
    logger.info("cage saved to %s", path)
    return dataclasses.replace(cage, path=str(path))


def asset_cages(asset, digest: str) -> list[Path]:
    """Files that may hold a cage of the asset's shells, whose :func:`shell_digest` is ``digest``: its own
    ``cage.npz`` and the cache's."""
    return [asset.cage_path, *sorted((cache_dir() / "cages").glob(f"{digest[:16]}-*.npz"))]


def find_cage(asset, digest: str) -> tuple[Cage | None, Cage | None]:
    """The asset's cage (its own or a cached one) whose :func:`shellsim.tetcage.geometry.cage_digest` is
    ``digest``, or None; and the first readable cage of the asset (None when it has none)."""
    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    shells = shell_digest(outer, inner)
    first = None
    for path in asset_cages(asset, shells):
        cage = _read(path, (outer, inner), shells)
        if cage is not None and cage.digest == digest:
            return cage, first or cage
        first = first or cage
    return None, first


def cage_for_motion(asset, motion, source: str | None = None) -> Cage:
    """The asset's cage (its own or a cached one) that ``motion`` (a :class:`shellsim.motion.format.Motion` or
    :class:`~shellsim.motion.format.MotionInfo`) moves, found by the cage digest its header records
    (:func:`shellsim.tetcage.geometry.cage_digest`); an :class:`InputError` (``source: ...``, default the
    motion's file) saying how they differ when there is none. A motion recording another digest of the
    asset (:meth:`neural.asset.Asset.digest`: a retrained field) is logged, and rendered all the same. A scene
    motion moves several cages, not one asset's: an :class:`InputError` naming its bodies."""
    bodies = motion.asset.get("bodies")
    if bodies:
        names = ", ".join(str(b.get("name")) for b in bodies)
        raise InputError(
            f"{source or motion.path or 'the motion'}: a scene motion of {len(bodies)} bodies ({names}), not "
            "of one asset's cage; render it as a scene (each body with its own asset), or draw the surfaces "
            "it carries without an asset"
        )
    made_for = motion.asset.get("digest")
    if made_for and "name" in motion.asset and made_for != asset.digest():
        logger.warning(
            "%s was made for another version of the asset %r (its field or shells changed since)",
            source or motion.path or "the motion",
            motion.asset["name"],
        )
    cage, first = find_cage(asset, motion.cage_digest)
    if cage is not None:
        return cage
    if first is None:
        try:
            first = load_or_build_cage(asset)
        except (ImportError, RuntimeError, ValueError, OSError) as err:  # fTetWild and friends
            raise InputError(f"{asset.cage_path}: no usable cage and building one failed ({err})") from None
    motion.check_against(first, source)  # raises, saying how the motion's cage differs, unless it was built
    return first
