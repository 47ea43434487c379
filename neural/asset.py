"""The asset on disk: ``asset.json`` + ``field.safetensors`` + ``shell_outer.ply`` + ``shell_inner.ply``
(+ ``cage.npz``, made on demand by :mod:`shellsim.tetcage`).

Loading validates everything and never executes code from the asset: JSON, safetensors and PLY only,
and every file name must stay inside the asset directory.

``asset.json`` (format version 1)::

    {"format": "shellsim-asset", "format_version": 1, "name": "lego",
     "normalisation": {"center": [x, y, z], "scale": k},   # x_unit = (x_world - center) * k
     "up": [0, 0, 1], "background": [1, 1, 1],
     "files": {"field": "field.safetensors", "shell_outer": "shell_outer.ply",
               "shell_inner": "shell_inner.ply"},
     "field": {...FieldConfig...}, "shell": {...}, "training": {...}, "metrics": {...}}

Shells, cage and cameras all live in the dataset's world frame.
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import NarrowBandConfig
from .errors import InputError
from .files import write_atomically, write_bytes_atomically, write_text_atomically

FORMAT = "shellsim-asset"
FORMAT_VERSION = 1
REQUIRED_FILES = ("field", "shell_outer", "shell_inner")
#: Weights an asset stores in half precision, widened back to float32 on loading: the hash table, nearly all
#: of a field's bytes (Instant-NGP keeps its tables in half precision too).
HALF_PRECISION = ("encoding.table",)
CAGE_FILE = "cage.npz"
VISIBILITY_FILE = "visibility.safetensors"  # neural.visibility's grid of what the training views saw


SHIPPED_PACKAGE = "shellsim_assets"  # the repository's assets/, installed as package data (pyproject.toml)


def shipped_assets_dir() -> Path:
    """Directory of the assets shipped with the installed package (``$SHELLSIM_ASSETS`` overrides it)."""
    env = os.environ.get("SHELLSIM_ASSETS")
    if env:
        return Path(env)
    from importlib.resources import files

    return Path(str(files(SHIPPED_PACKAGE)))


def resolve_asset(spec: str | os.PathLike) -> tuple[Path, bool]:
    """``--asset PATH`` (any asset directory) or ``--asset NAME`` (a shipped asset) -> (its directory,
    whether it was found by name among the shipped ones, which are never written to)."""
    path = Path(spec)
    if path.is_dir():
        return path, False
    shipped = shipped_assets_dir() / str(spec)
    if os.sep not in str(spec) and shipped.is_dir():
        return shipped, True
    available = sorted(p.name for p in shipped_assets_dir().glob("*/asset.json") for p in [p.parent])
    raise InputError(
        f"asset {str(spec)!r}: no such directory and no shipped asset of that name "
        f"(shipped: {', '.join(available) or 'none'})"
    )


def _inside(root: Path, name: str, what: str) -> Path:
    if not isinstance(name, str) or not name or Path(name).is_absolute():
        raise InputError(f"{root / 'asset.json'}: files.{what} must be a relative file name, got {name!r}")
    target = (root / name).resolve()
    if root.resolve() not in target.parents:
        raise InputError(f"{root / 'asset.json'}: files.{what} = {name!r} points outside the asset")
    return target


@dataclass
class Asset:
    """A validated asset directory. ``meta`` is the parsed ``asset.json``; ``shipped``: found by name among
    the installed package's assets, so nothing may be written into it (its cages with other settings go to
    the cache, see :func:`shellsim.tetcage.load_or_build_cage`)."""

    root: Path
    meta: dict
    shipped: bool = False

    @property
    def name(self) -> str:
        return str(self.meta.get("name", self.root.name))

    def file(self, key: str) -> Path:
        """Absolute path of ``files[key]``, checked to lie inside the asset."""
        return _inside(self.root, self.meta["files"][key], key)

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.meta["normalisation"]["center"], dtype=np.float64)

    @property
    def scale(self) -> float:
        return float(self.meta["normalisation"]["scale"])

    @property
    def up(self) -> np.ndarray:
        return np.asarray(self.meta.get("up", [0.0, 0.0, 1.0]), dtype=np.float64)

    @property
    def background(self) -> tuple[float, float, float]:
        """Colour behind the object (the training background)."""
        return tuple(float(c) for c in self.meta.get("background", (1.0, 1.0, 1.0)))

    @property
    def training_downscale(self) -> int:
        """The image downscale the asset was trained at (its held-out views are evaluated at it)."""
        return int(self.meta.get("training", {}).get("downscale", 1))

    def narrowband_config(self):
        """The :class:`~neural.config.NarrowBandConfig` stored with the asset (world units)."""
        try:
            return NarrowBandConfig(**self.meta.get("narrowband", {}))
        except (TypeError, ValueError) as err:
            raise InputError(f"{self.root / 'asset.json'}: invalid narrowband settings ({err})") from None

    @property
    def cage_path(self) -> Path:
        return self.root / CAGE_FILE

    def digest(self) -> str:
        """sha256 (hex) of the asset's content: the normalisation and field settings of ``asset.json``, the
        field weights and both shells (what a motion records of the asset it was made for)."""
        h = hashlib.sha256(json.dumps([self.meta.get(k) for k in ("normalisation", "field")]).encode())
        for key in ("field", "shell_outer", "shell_inner"):
            with open(self.file(key), "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        return h.hexdigest()

    @property
    def contraction(self):
        """For an asset whose field lives in contracted space, the map of world points into it
        (:class:`~neural.field.contraction.ContractionMap`, the field's own: the unit ball the normalised
        capture's, of radius ``1 / scale``); None for a bounded one."""
        from .field.contraction import ContractionMap

        if not self.meta.get("field", {}).get("contract", False):
            return None
        return ContractionMap(self.center, 1.0 / self.scale)

    @property
    def cut(self):
        """The region of a cut asset (:class:`neural.shell.cutout.Cut`: its shells hold the object cut out
        of a capture, its ``backdrop_outer`` / ``backdrop_inner`` files the rest); None for any other."""
        from .shell.cutout import Cut

        if "cut" not in self.meta:
            return None
        return Cut.from_dict(self.meta["cut"], f"{self.root / 'asset.json'}: cut")

    def backdrop_meshes(self):
        """(M+, M-) of a cut asset's backdrop, ``trimesh.Trimesh`` in world coordinates."""
        return load_mesh(self.file("backdrop_outer")), load_mesh(self.file("backdrop_inner"))

    def visibility(self):
        """The :class:`~neural.visibility.Visibility` of what the asset's training views saw, None for an
        asset trained before it was recorded."""
        from .visibility import Visibility

        if "visibility" not in self.meta.get("files", {}):
            return None
        path = self.file("visibility")
        if not path.is_file():
            raise InputError(f"{path}: file listed in asset.json is missing")
        return Visibility.load(path)

    def outer_mesh(self):
        """M+ as a ``trimesh.Trimesh`` in world coordinates."""
        return load_mesh(self.file("shell_outer"))

    def inner_mesh(self):
        """M- as a ``trimesh.Trimesh`` in world coordinates."""
        return load_mesh(self.file("shell_inner"))


def load_mesh(path: Path, require_closed: bool = True):
    """Read a triangle mesh (PLY/OBJ/STL/OFF...) with trimesh; empty, garbage or open meshes are errors."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: mesh file not found")
    try:
        mesh = trimesh.load(path, force="mesh", process=True)
    except Exception as err:  # trimesh raises many types for garbage input
        raise InputError(f"{path}: cannot read a triangle mesh ({err})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"{path}: contains no triangles")
    if not np.isfinite(mesh.vertices).all():
        raise InputError(f"{path}: vertex coordinates contain NaN or infinity")
    if require_closed and not mesh.is_watertight:
        raise InputError(f"{path}: mesh is not closed (watertight); a solid needs a closed surface")
    return mesh


def load_asset(spec: str | os.PathLike) -> Asset:
    """Find and validate an asset; every problem is one :class:`InputError` naming the file."""
    root, shipped = resolve_asset(spec)
    meta_path = root / "asset.json"
    if not meta_path.is_file():
        raise InputError(f"{root}: not an asset (asset.json missing)")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"{meta_path}: malformed JSON ({err})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(f"{meta_path}: not a shellsim asset (format must be {FORMAT!r})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise InputError(
            f"{meta_path}: format_version {meta.get('format_version')!r} is not supported "
            f"(this shellsim reads {FORMAT_VERSION})"
        )
    for key in ("normalisation", "files", "field"):
        if not isinstance(meta.get(key), dict):
            raise InputError(f"{meta_path}: missing or invalid key {key!r}")
    norm = meta["normalisation"]
    try:
        center = np.asarray(norm["center"], dtype=np.float64)
        scale = float(norm["scale"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{meta_path}: normalisation needs center [x, y, z] and scale > 0") from None
    if center.shape != (3,) or not np.isfinite(center).all() or not (scale > 0 and np.isfinite(scale)):
        raise InputError(f"{meta_path}: normalisation needs center [x, y, z] and scale > 0")
    _check_optional_keys(meta_path, meta)
    asset = Asset(root, meta, shipped)
    for key in REQUIRED_FILES:
        if key not in meta["files"]:
            raise InputError(f"{meta_path}: files.{key} is missing")
        if not asset.file(key).is_file():
            raise InputError(f"{asset.file(key)}: file listed in asset.json is missing")
    return asset


def _check_optional_keys(meta_path: Path, meta: dict) -> None:
    """``up`` (3 finite numbers, not all 0), ``background`` (3 in [0, 1]), ``name`` (a string) and
    ``training.downscale`` (a whole number >= 1) when present; anything else is an :class:`InputError`."""

    def three(value) -> np.ndarray | None:
        ok = isinstance(value, list) and len(value) == 3
        ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        return np.asarray(value, dtype=np.float64) if ok and np.isfinite(value).all() else None

    up, bg = three(meta.get("up", [0, 0, 1])), three(meta.get("background", [1, 1, 1]))
    if up is None or not np.any(up):
        raise InputError(f"{meta_path}: 'up' must be 3 finite numbers, not all 0, got {meta.get('up')!r}")
    if bg is None or bg.min() < 0 or bg.max() > 1:
        raise InputError(
            f"{meta_path}: 'background' must be 3 numbers in [0, 1], got {meta.get('background')!r}"
        )
    if not isinstance(meta.get("name", ""), str):
        raise InputError(f"{meta_path}: 'name' must be a string, got {meta['name']!r}")
    training = meta.get("training", {})
    downscale = training.get("downscale", 1) if isinstance(training, dict) else None
    number = isinstance(downscale, int | float) and not isinstance(downscale, bool)
    if not (number and downscale >= 1 and float(downscale).is_integer()):
        raise InputError(
            f"{meta_path}: 'training.downscale' must be a whole number >= 1, "
            f"got {downscale if isinstance(training, dict) else training!r}"
        )


def write_safetensors(path, tensors: dict, metadata: dict[str, str] | None = None) -> None:
    """Write ``tensors`` to ``path`` as safetensors, atomically (:mod:`neural.files`), with the usual
    permissions (0666 less the umask; safetensors' own ``save_file`` makes 0600 files)."""
    from safetensors.torch import save

    write_bytes_atomically(path, save(tensors, metadata=metadata))


def save_asset(root, field, outer, inner, meta: dict, visibility=None) -> Path:
    """Write an asset directory: ``field.safetensors`` (:data:`HALF_PRECISION` weights as float16), the two
    shells as PLY, with ``visibility`` (a :class:`~neural.visibility.Visibility`) ``visibility.safetensors``,
    and ``asset.json`` (last, so a directory with an ``asset.json`` is complete). ``meta`` supplies
    everything but format/files/field/visibility."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    files = {"field": "field.safetensors", "shell_outer": "shell_outer.ply", "shell_inner": "shell_inner.ply"}
    if visibility is not None:
        files["visibility"] = VISIBILITY_FILE
        visibility.save(root / VISIBILITY_FILE)
        meta = {**meta, "visibility": visibility.record()}
    state = {k: v.detach().contiguous().cpu() for k, v in field.state_dict().items()}
    state.update({k: state[k].half() for k in HALF_PRECISION})
    write_safetensors(root / files["field"], state)
    outer.export(root / files["shell_outer"])
    inner.export(root / files["shell_inner"])
    full = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        **meta,
        "files": files,
        "field": field.config_dict(),
    }
    write_meta(root, full)
    return root


def load_field(asset: Asset, device: str = "cpu"):
    """The asset's ``ShellField`` with its weights (safetensors; no code is executed)."""
    from safetensors.torch import load_file

    from .field import ShellField

    path = asset.file("field")
    try:
        field = ShellField.from_config_dict(
            asset.meta["field"], center=tuple(asset.center), scale=asset.scale
        )
    except (TypeError, ValueError, KeyError) as err:
        raise InputError(f"{asset.root / 'asset.json'}: invalid field configuration ({err})") from None
    try:
        state = load_file(str(path))
    except Exception as err:  # safetensors raises several error types for corrupt files
        raise InputError(f"{path}: cannot read field weights ({err})") from None
    try:
        field.load_state_dict(state)
    except RuntimeError as err:
        raise InputError(
            f"{path}: weights do not match the field configuration in asset.json ({err})"
        ) from None
    return field.to(device).eval()


def refuse_shipped(asset: Asset, what: str) -> None:
    """An :class:`InputError` when ``asset`` is a shipped one: ``what`` would write into it."""
    if asset.shipped:
        raise InputError(
            f"asset {asset.name!r} is shipped with shellsim and is never modified ({what} would write into "
            f"{asset.root}); copy that directory and give the copy's path"
        )


def replace_shells(asset: Asset, outer, inner, shell_meta: dict) -> None:
    """Swap in new shells (written to temporary files, then renamed) and record their settings; metrics that
    depend on the shells (all but ``stage1_full_ray``) move to ``metrics["earlier_shells"]``."""
    for key, mesh in (("shell_outer", outer), ("shell_inner", inner)):
        write_atomically(asset.file(key), lambda tmp, m=mesh: m.export(tmp))
    asset.meta["shell"] = shell_meta
    metrics = asset.meta.setdefault("metrics", {})
    stale = {k: metrics.pop(k) for k in list(metrics) if k not in ("stage1_full_ray", "earlier_shells")}
    if stale:
        metrics["earlier_shells"] = {**metrics.get("earlier_shells", {}), **stale}
    write_meta(asset.root, asset.meta)


def command_line() -> str:
    """The ``shellsim`` command this process runs, shell-quoted (recorded in ``asset.json``)."""
    return " ".join(shlex.quote(a) for a in ["shellsim", *sys.argv[1:]])


def write_meta(root: Path, meta: dict) -> None:
    """Write ``asset.json`` atomically."""
    write_text_atomically(Path(root) / "asset.json", json.dumps(meta, indent=1))
