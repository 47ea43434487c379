"""Camera poses from plain photos (structure from motion with pycolmap) and COLMAP models as datasets.

:func:`run_sfm` runs COLMAP's own pipeline through its Python bindings, all on the CPU: SIFT features,
exhaustive (or sequential) matching with geometric verification, incremental mapping, one ``OPENCV``
camera (``fx fy cx cy k1 k2 p1 p2``) shared by every photo. :func:`transforms_from_reconstruction` turns
a COLMAP reconstruction into an instant-ngp / nerfstudio ``transforms.json`` dict; ``shellsim poses``
writes it and :func:`model_transforms` hands it to :func:`neural.data.datasets.load_dataset`, so a
COLMAP model directory and the ``transforms.json`` made from it load as the same cameras.

Conventions of that dict (those of instant-ngp's ``colmap2nerf.py``, and of the rest of this project):
COLMAP's world-to-camera poses (OpenCV camera axes: x right, y down, looking down +z) become
camera-to-world ``transform_matrix`` in OpenGL axes (x right, y up, looking down -z); the world is then
moved by one similarity ``x' = s R (x - c)`` so that ``c``, the point closest to every optical axis
(the point the capture looks at), is the origin, the mean camera up vector is +z, and the mean camera
distance from the origin is 4. ``aabb_scale`` is the smallest power of two whose cube, in multiples of
the loader's object cube, holds 99% of the reconstructed points (the background the photos see).
``applied_transform`` records the (3, 4) similarity ``[s R | -s R c]`` from COLMAP's world.

pycolmap is an optional dependency (``pip install -e ".[sfm]"``); only the functions that need it
import it.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError, ShellsimError
from .datasets import NGP_CUBE_FRACTION, _focus_point

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
MODEL_FILES = ("cameras", "images", "points3D")
MEAN_CAMERA_DISTANCE = 4.0  # colmap2nerf's scale: instant-ngp's default box then frames the object
AABB_POINT_QUANTILE = 0.99
MAX_AABB_SCALE = 128
SEQUENTIAL_OVERLAP = 10
UPSAMPLE_BELOW = 1000  # SIFT doubles images whose long side is at most this (COLMAP's first_octave -1)
# COLMAP camera models whose parameters map onto OpenCV's k1 k2 p1 p2 (missing ones are 0)
_MODEL_PARAMS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
}


def require_pycolmap():
    """The ``pycolmap`` module, or a :class:`ShellsimError` saying how to install it."""
    try:
        import pycolmap
    except ImportError:
        raise ShellsimError(
            'structure from motion needs pycolmap, which is not installed: pip install -e ".[sfm]"'
        ) from None
    return pycolmap


# ---------------------------------------------------------------------------------------------------
# structure from motion


@dataclass
class SfmResult:
    """What :func:`run_sfm` made.

    Attributes:
        reconstruction: the largest pycolmap ``Reconstruction`` (also written to ``work_dir/sparse/0``).
        names: every image name given to COLMAP (readable, one size), relative to the image directory.
        skipped: {name: reason} for the images of the directory not given to COLMAP (unreadable, or of
            another size than the rest).
        unregistered: names of ``names`` that the mapper could not pose.
        seconds: wall time per stage (``features``, ``matching``, ``mapping``).
    """

    reconstruction: object
    names: list[str]
    skipped: dict[str, str]
    unregistered: list[str]
    seconds: dict[str, float] = field(default_factory=dict)


def list_images(image_dir: Path) -> tuple[list[str], dict[str, str]]:
    """(names of the readable images of one size, {name: reason} for the others), sorted by name.

    Images are the files with a suffix in :data:`IMAGE_SUFFIXES` directly in ``image_dir``. The size
    most images share wins (one camera); each other image is listed with its reason.
    """
    files = sorted(p for p in image_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    sizes, skipped = {}, {}
    for path in files:
        try:
            with Image.open(path) as im:
                im.load()  # decodes the pixels: a truncated file fails here, not inside COLMAP
                sizes[path.name] = im.size
        except (OSError, UnidentifiedImageError, ValueError) as err:
            skipped[path.name] = f"unreadable ({err})"
    if not sizes:
        return [], skipped
    values = list(sizes.values())
    common = max(set(values), key=values.count)
    for name, size in sizes.items():
        if size != common:
            skipped[name] = f"{size[0]}x{size[1]}, the other images are {common[0]}x{common[1]}"
    return [n for n in sizes if n not in skipped], skipped


def run_sfm(
    image_dir: str | os.PathLike,
    work_dir: str | os.PathLike,
    matching: str,
    max_features: int,
    threads: int | None = None,
    progress: bool = True,
) -> SfmResult:
    """Recover the poses of the photos in ``image_dir`` with COLMAP; files go to ``work_dir``.

    Writes ``work_dir/database.db`` (features and matches) and ``work_dir/sparse/0`` (the model), both
    with the image names of ``image_dir``.

    Args:
        image_dir: directory of photos of one size (see :func:`list_images`).
        work_dir: an empty or new directory.
        matching: ``"exhaustive"`` (every pair) or ``"sequential"`` (each photo with the next
            :data:`SEQUENTIAL_OVERLAP` in name order, wrapping round: for videos and orbits).
        max_features: SIFT features kept per image.
        threads: CPU threads for every stage (default: the cores this process may use).
        progress: show tqdm bars per stage.

    Raises :class:`InputError` when the directory has no readable image; a mapper that registers
    nothing returns an empty reconstruction (the caller decides what is too few).
    """
    import time

    from tqdm import tqdm

    pycolmap = require_pycolmap()
    if matching not in ("exhaustive", "sequential"):
        raise ValueError(f"matching: expected 'exhaustive' or 'sequential', got {matching!r}")
    if not (isinstance(max_features, int) and max_features > 0):
        raise ValueError(f"max_features: expected a positive int, got {max_features!r}")
    threads = threads or len(os.sched_getaffinity(0))
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    names, skipped = list_images(image_dir)
    for name, reason in skipped.items():
        log.warning("%s: skipped: %s", image_dir / name, reason)
    if not names:
        raise InputError(
            f"{image_dir}: no readable images ({', '.join(IMAGE_SUFFIXES)})"
            + (f"; {len(skipped)} unreadable" if skipped else "")
        )
    work_dir.mkdir(parents=True, exist_ok=True)
    database = work_dir / "database.db"
    sparse = work_dir / "sparse"
    # COLMAP sees links 00000.jpg, ... (its pair lists split names at spaces); names are restored at the end
    staged = _fresh_dir(work_dir / "staged")
    links = [f"{k:05d}{Path(name).suffix.lower()}" for k, name in enumerate(names)]
    for link, name in zip(links, names, strict=True):
        (staged / link).symlink_to((image_dir / name).resolve())
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 2  # COLMAP's own log lines
    pycolmap.set_random_seed(0)
    device = pycolmap.Device.cpu
    seconds = {}

    # features: chunks of `threads` images per call, so that the bar moves; one OPENCV camera for all
    start = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "OPENCV"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.max_num_features = max_features
    with Image.open(image_dir / names[0]) as im:
        extraction.sift.first_octave = -1 if max(im.size) <= UPSAMPLE_BELOW else 0
    with tqdm(total=len(names), desc="SIFT features", unit="image", disable=not progress) as bar:
        for chunk in _chunks(links, threads):
            pycolmap.extract_features(
                database,
                staged,
                image_names=chunk,
                camera_mode=pycolmap.CameraMode.SINGLE,
                reader_options=reader,
                extraction_options=extraction,
                device=device,
            )
            if reader.existing_camera_id < 0:
                with contextlib.closing(pycolmap.Database.open(str(database))) as db:
                    reader.existing_camera_id = db.read_all_cameras()[0].camera_id
            bar.update(len(chunk))
    seconds["features"] = time.perf_counter() - start

    # matching: explicit pairs, in chunks, each verified geometrically (two-view RANSAC)
    start = time.perf_counter()
    pairs = _pairs(links, matching)
    options = pycolmap.FeatureMatchingOptions()
    options.num_threads = threads
    with (
        tempfile.TemporaryDirectory() as tmp,
        tqdm(total=len(pairs), desc="matching", unit="pair", disable=not progress) as bar,
    ):
        pair_file = Path(tmp) / "pairs.txt"
        for chunk in _chunks(pairs, max(16, 8 * threads)):
            pair_file.write_text("".join(f"{a} {b}\n" for a, b in chunk), encoding="utf-8")
            pycolmap.match_image_pairs(
                database,
                matching_options=options,
                pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(pair_file)),
                device=device,
            )
            bar.update(len(chunk))
    seconds["matching"] = time.perf_counter() - start

    # incremental mapping: a new model where one stops growing, the largest kept; the bar counts poses
    start = time.perf_counter()
    _fresh_dir(sparse)
    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = threads
    mapper.multiple_models = True
    mapper.random_seed = 0
    with tqdm(total=len(names), desc="mapping", unit="image", disable=not progress) as bar:

        def registered():
            bar.update(1)

        models = pycolmap.incremental_mapping(
            database, staged, sparse, options=mapper, next_image_callback=registered
        )
        reconstruction = pycolmap.Reconstruction()
        if models:
            reconstruction = models[max(models, key=lambda k: models[k].num_reg_images())]
        bar.n = reconstruction.num_reg_images()  # the first pair registers two images in one callback
        bar.refresh()
    seconds["mapping"] = time.perf_counter() - start
    original = dict(zip(links, names, strict=True))
    for image in reconstruction.images.values():
        image.name = original[image.name]
    with contextlib.closing(pycolmap.Database.open(str(database))) as db:
        for image in db.read_all_images():
            image.name = original[image.name]
            db.update_image(image)
    shutil.rmtree(sparse)
    reconstruction.write(_fresh_dir(sparse / "0"))  # the chosen model, named as in image_dir
    shutil.rmtree(staged)
    posed = {im.name for im in reconstruction.images.values() if im.has_pose}
    unregistered = [name for name in names if name not in posed]
    for name in unregistered:
        log.warning("%s: not posed (too few verified matches with the posed photos)", image_dir / name)
    return SfmResult(reconstruction, names, skipped, unregistered, seconds)


def _chunks(items: list, size: int):
    for i in range(0, len(items), size):
        yield items[i : i + size]


def _pairs(names: list[str], matching: str) -> list[tuple[str, str]]:
    if matching == "exhaustive":
        return list(itertools.combinations(names, 2))
    n = len(names)
    steps = range(1, min(SEQUENTIAL_OVERLAP, n // 2) + 1)
    return sorted({tuple(sorted((names[i], names[(i + k) % n]))) for i in range(n) for k in steps})


def _fresh_dir(path: Path) -> Path:
    if path.exists():
        shutil.rmtree(path)
    path.mkdir(parents=True)
    return path


# ---------------------------------------------------------------------------------------------------
# COLMAP reconstruction -> transforms.json


def opencv_intrinsics(camera) -> dict:
    """``fl_x fl_y cx cy k1 k2 p1 p2 w h`` of a pycolmap ``Camera`` of a model in :data:`_MODEL_PARAMS`
    (COLMAP's principal point already has pixel centres at +0.5, as here); others are an InputError."""
    model = camera.model.name
    if model not in _MODEL_PARAMS:
        raise InputError(
            f"camera {camera.camera_id}: COLMAP camera model {model} is not supported "
            f"(only {', '.join(_MODEL_PARAMS)}: OpenCV k1 k2 p1 p2 distortion at most)"
        )
    values = dict(zip(_MODEL_PARAMS[model], map(float, camera.params), strict=True))
    fx = values.get("fx", values.get("f"))
    fy = values.get("fy", values.get("f"))
    out = {"fl_x": fx, "fl_y": fy, "cx": values["cx"], "cy": values["cy"]}
    out.update({k: values.get(k, 0.0) for k in ("k1", "k2", "p1", "p2")})
    out.update({"w": int(camera.width), "h": int(camera.height)})
    return out


def colmap_to_opengl(cam_from_world: np.ndarray) -> np.ndarray:
    """(4, 4) OpenGL camera-to-world from a (3, 4) COLMAP world-to-camera ``[R | t]`` (OpenCV axes)."""
    c2w = np.eye(4)
    rot, t = cam_from_world[:, :3], cam_from_world[:, 3]
    c2w[:3, :3] = rot.T
    c2w[:3, 3] = -rot.T @ t
    c2w[:3, 1:3] *= -1  # camera y down -> up, +z forward -> -z forward
    return c2w


def normalising_similarity(c2w: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R (3, 3), c (3,)) of ``x' = s R (x - c)`` for OpenGL cameras ``c2w`` (N, 4, 4): ``c`` the point
    closest to every optical axis, ``R`` turning the mean camera up (+y) to +z, ``s`` making the mean
    camera distance :data:`MEAN_CAMERA_DISTANCE` (see the module docstring)."""
    center = _focus_point(c2w)
    up = c2w[:, :3, 1].mean(axis=0)
    rot = _rotation_between(up, np.array([0.0, 0.0, 1.0]))
    distance = float(np.mean(np.linalg.norm(c2w[:, :3, 3] - center, axis=1)))
    if not distance > 0:
        raise InputError("every camera sits at the point they look at: the scene has no scale")
    return MEAN_CAMERA_DISTANCE / distance, rot, center


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) rotation taking the direction of ``a`` to unit ``b`` (identity when ``a`` is ~0)."""
    norm = np.linalg.norm(a)
    if norm < 1e-9:
        return np.eye(3)
    a = a / norm
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-9:  # opposite: half a turn about any axis normal to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def transforms_from_reconstruction(reconstruction, image_dir: Path, base: Path) -> dict:
    """The instant-ngp / nerfstudio ``transforms.json`` dict of a pycolmap ``Reconstruction``.

    Args:
        reconstruction: posed images (images without a pose are left out with a warning).
        image_dir: the directory the model's image names are relative to.
        base: the directory ``file_path`` is written relative to (where the JSON goes).

    Intrinsics are top-level when every posed image shares one camera, per frame otherwise; frames are
    sorted by image name; axes, centre and scale as in the module docstring.
    """
    images = sorted(reconstruction.images.values(), key=lambda im: im.name)
    unposed = [im.name for im in images if not im.has_pose]
    if unposed:
        log.warning("%d images of the COLMAP model have no pose and are left out: %s", len(unposed), unposed)
    images = [im for im in images if im.has_pose]
    if not images:
        raise InputError("the COLMAP model has no posed image")
    c2w = np.stack([colmap_to_opengl(np.asarray(im.cam_from_world().matrix())) for im in images])
    scale, rot, center = normalising_similarity(c2w)
    c2w[:, :3, :3] = rot @ c2w[:, :3, :3]
    c2w[:, :3, 3] = scale * (c2w[:, :3, 3] - center) @ rot.T
    applied = np.hstack([scale * rot, (-scale * rot @ center)[:, None]])
    cameras = {im.camera_id: opencv_intrinsics(reconstruction.cameras[im.camera_id]) for im in images}
    meta = {"camera_model": "OPENCV"}
    if len(cameras) == 1:
        meta.update(next(iter(cameras.values())))
    points = [p.xyz for p in reconstruction.points3D.values()]
    if points:
        points = scale * (np.asarray(points) - center) @ rot.T
        reach = np.quantile(np.abs(points).max(axis=1), AABB_POINT_QUANTILE)
        ratio = reach / (NGP_CUBE_FRACTION * MEAN_CAMERA_DISTANCE)
        meta["aabb_scale"] = int(min(MAX_AABB_SCALE, 2 ** math.ceil(math.log2(max(ratio, 1.0)))))
    meta["applied_transform"] = applied.tolist()
    frames = []
    for im, m in zip(images, c2w, strict=True):
        frame = {"file_path": Path(os.path.relpath(image_dir / im.name, base)).as_posix()}
        frame["transform_matrix"] = m.tolist()
        frame["colmap_im_id"] = int(im.image_id)
        if len(cameras) > 1:
            frame.update(cameras[im.camera_id])
        frames.append(frame)
    meta["frames"] = frames
    return meta


# ---------------------------------------------------------------------------------------------------
# COLMAP model directories as datasets


def _is_model(path: Path) -> bool:
    return any(all((path / f"{n}{ext}").is_file() for n in MODEL_FILES) for ext in (".bin", ".txt"))


def find_model(path: Path) -> Path | None:
    """The COLMAP model directory of ``path``: ``path/sparse/0``, ``path/0`` or ``path`` itself, the first
    that holds ``cameras``, ``images`` and ``points3D`` (``.bin`` or ``.txt``); else None."""
    for candidate in (path / "sparse" / "0", path / "0", path):
        if _is_model(candidate):
            return candidate
    return None


def model_image_dir(model: Path, must_exist: bool = True) -> Path:
    """The ``images/`` directory of the scene a model belongs to: ``SCENE/images`` for a model at
    ``SCENE/sparse/0`` (or ``SCENE/sparse``); when there is none, an InputError, or with ``must_exist``
    False (cameras only, e.g. ``render --cameras``) the first candidate."""
    model = model.resolve()
    candidates = [model.parent.parent / "images", model.parent / "images"]
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    if not must_exist:
        return candidates[0]
    raise InputError(
        f"{model}: COLMAP model without its photos: no {' or '.join(map(str, candidates))} directory"
    )


def model_transforms(model: Path, need_images: bool = True) -> tuple[dict, Path]:
    """(``transforms.json`` dict, the model file errors should name) for a COLMAP model directory;
    ``file_path`` is relative to the model directory. Used by :func:`load_dataset` and, without
    ``need_images`` (the photos may be elsewhere or gone), by :func:`load_camera_file`."""
    pycolmap = require_pycolmap()
    image_dir = model_image_dir(model, must_exist=need_images)
    try:
        reconstruction = pycolmap.Reconstruction(str(model))
    except Exception as err:  # pycolmap raises bare ValueError / RuntimeError on a corrupt model
        reason = (str(err).strip().splitlines() or [type(err).__name__])[-1]
        raise InputError(f"{model}: cannot read the COLMAP model: {reason}") from None
    label = model / ("images.bin" if (model / "images.bin").is_file() else "images.txt")
    try:
        return transforms_from_reconstruction(reconstruction, image_dir, model), label
    except InputError as err:
        raise InputError(f"{label}: {err}") from None


# ---------------------------------------------------------------------------------------------------
# evaluation


def align_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991) of corresponding points.

    Args:
        src, dst: (N, 3) points, N >= 3 not all on one line.
    Returns:
        s (float), R (3, 3) proper rotation, t (3,).
    """
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"src, dst: expected two (N, 3) arrays with N >= 3, got {src.shape}, {dst.shape}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    u, sigma, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u) * np.linalg.det(vt))])
    rot = u @ d @ vt
    var = (a**2).sum() / len(src)
    if not var > 0:
        raise ValueError("src: all points coincide")
    scale = float(np.trace(np.diag(sigma) @ d) / var)
    return scale, rot, mu_d - scale * rot @ mu_s
