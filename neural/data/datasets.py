"""Posed-image datasets: NeRF-synthetic ``transforms_{train,val,test}.json`` and instant-ngp / nerfstudio
``transforms.json``, loaded into one :class:`SceneData`.

Both formats store per-frame ``transform_matrix`` camera-to-world in OpenGL axes (see
:mod:`neural.data.cameras`) and a ``file_path`` relative to the JSON file (NeRF-synthetic omits the
``.png`` extension). Intrinsics are read by one rule for both: keys of the frame override keys of the file;
``fl_x`` (else ``0.5 w / tan(camera_angle_x / 2)``), ``fl_y`` (else from ``camera_angle_y``, else
``fl_x``), ``cx = w / 2``, ``cy = h / 2``, ``k1 k2 p1 p2 = 0`` by default; ``w``, ``h`` default to the
image's size. Every pose must be rigid (:func:`camera_pose`) and every intrinsic valid (:func:`_number`);
errors name the file and the frame with its ``file_path``, or the top-level key.

A COLMAP model (``SCENE/sparse/0/{cameras,images,points3D}.bin`` beside ``SCENE/images/``; ``--data`` is
``SCENE``, ``SCENE/sparse`` or ``SCENE/sparse/0``) is read with pycolmap and converted by
:func:`neural.data.colmap.transforms_from_reconstruction`, the conversion ``shellsim poses`` writes, then
loaded and normalised as instant-ngp (format ``"colmap"``).

Normalisation into the field's unit cube ``u = (x - center) * scale``:

- NeRF-synthetic: ``center = 0``, ``scale = 1 / bound`` with ``bound = 1.5`` (lego fits [-1.5, 1.5]^3);
  up is +z.
- instant-ngp: ``center`` is the point closest, in least squares, to every camera's optical axis (the
  point the capture looks at); ``bound = NGP_CUBE_FRACTION * mean camera distance from center``.
  This is instant-ngp's own object cube: colmap2nerf scales captures to a mean camera distance of 4, and
  instant-ngp's default ``scale`` 0.33 makes its unit cube ``0.5 / 0.33 = 1.52`` units wide each side of
  the centre, i.e. 0.38 of the camera distance. ``aabb_scale`` says how far the *background* reaches
  beyond that cube (in multiples of it); an object-centred field does not model it, so it only sets
  :attr:`SceneData.scene_radius`, the distance beyond which nothing is seen, for far planes and
  background models. Up is the normalised mean of the cameras' up vectors.

Either bound can be overridden (``bound=``, world units).
"""

from __future__ import annotations

import json
import logging
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError
from .cameras import Cameras, Normalisation, scaled_size

log = logging.getLogger(__name__)

SYNTHETIC_SPLITS = ("train", "val", "test")
SYNTHETIC_BOUND = 1.5
NGP_CUBE_FRACTION = (0.5 / 0.33) / 4.0
SUPPORTED_CAMERA_MODELS = ("OPENCV", "PINHOLE")
POSE_TOLERANCE = 1e-2  # on |R^T R - I|: poses rounded to 3 decimals pass, a 1 % scale or shear does not


@dataclass(eq=False)
class SceneData:
    """A loaded dataset: images, cameras, the train/test split and the world-to-unit-cube map.

    Attributes:
        images: (N, H, W, 3) float32 in [0, 1], composited on ``background`` where the images have alpha.
        alphas: (N, H, W) float32 coverage, or None when no image has an alpha channel.
        cameras: the N cameras at the loaded (downscaled) resolution.
        train_idx, test_idx: int64 indices into the N views; every ``holdout_every``-th view
            (0, 8, 16, ... by default) is held out for testing.
        normalisation: world -> unit cube [-1, 1]^3 that the field covers.
        up: (3,) float64 unit world up axis (gravity points along -up).
        background: (3,) float32 RGB the alpha images were composited on.
        source: the dataset directory.
        format: ``"nerf-synthetic"``, ``"instant-ngp"`` or ``"colmap"``.
        scene_radius: world distance from ``normalisation.center`` within which the whole scene lies
            (``bound`` for NeRF-synthetic; ``aabb_scale * bound`` for instant-ngp).
    """

    images: np.ndarray
    alphas: np.ndarray | None
    cameras: Cameras
    train_idx: np.ndarray
    test_idx: np.ndarray
    normalisation: Normalisation
    up: np.ndarray
    background: np.ndarray
    source: Path
    format: str
    scene_radius: float

    def __len__(self) -> int:
        return len(self.cameras)


@dataclass(eq=False)
class _Frame:
    json_path: Path
    index: int  # position in the JSON's frames list
    meta: dict  # the whole JSON (shared keys)
    frame: dict
    c2w: np.ndarray  # (4, 4)
    image_path: Path | None  # None: a camera-file frame without file_path


def load_dataset(
    path: str | os.PathLike,
    downscale: float = 1,
    background=(1.0, 1.0, 1.0),
    holdout_every: int = 8,
    bound: float | None = None,
) -> SceneData:
    """Load a NeRF-synthetic or instant-ngp / nerfstudio dataset (format detected from the files).

    Args:
        path: the dataset directory, or one of its ``transforms*.json`` files.
        downscale: images shrink by this factor with an area filter; intrinsics follow.
        background: (3,) RGB in [0, 1] that RGBA images are composited on.
        holdout_every: every k-th loaded view is a test view (indices 0, k, 2k, ...); 0 holds out none.
        bound: half-width in world units of the cube around the scene centre the field covers;
            default per format (see the module docstring).

    Listed images that do not exist are skipped with one warning; none existing is an :class:`InputError`,
    and so is malformed JSON or a frame missing a required key.
    """
    background = np.asarray(background, dtype=np.float32)
    if background.shape != (3,) or np.any(background < 0) or np.any(background > 1):
        raise ValueError(f"background: expected 3 values in [0, 1], got {background.tolist()}")
    if not isinstance(holdout_every, int | np.integer) or holdout_every < 0 or holdout_every == 1:
        raise ValueError(f"holdout_every: expected 0 (no hold-out) or an int >= 2, got {holdout_every!r}")
    if bound is not None and not (np.isfinite(bound) and bound > 0):
        raise ValueError(f"bound: expected a positive number, got {bound!r}")
    scaled_size(1, downscale)  # validates downscale

    root, fmt, json_paths = _locate(Path(path))
    frames = [f for jp in json_paths for f in _read_frames(jp)]
    if not frames:
        raise InputError(f"{', '.join(map(str, json_paths))}: no frames listed")
    present = [f for f in frames if f.image_path.is_file()]
    missing = [f for f in frames if not f.image_path.is_file()]
    if missing:
        names = ", ".join(_relative(f.image_path, root) for f in missing)
        log.warning(
            "%s: %d of %d listed images are missing and skipped: %s", root, len(missing), len(frames), names
        )
    if not present:
        raise InputError(
            f"{root}: none of the {len(frames)} images listed in "
            f"{', '.join(p.name for p in json_paths)} exist (first: {missing[0].image_path})"
        )

    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        loaded = list(pool.map(lambda f: _load_image(f.image_path, downscale, background), present))
    first = loaded[0][0].shape
    for f, (rgb, _, _) in zip(present, loaded, strict=True):
        if rgb.shape != first:
            raise InputError(
                f"{f.image_path}: image is {rgb.shape[1]}x{rgb.shape[0]} but {present[0].image_path} is "
                f"{first[1]}x{first[0]} (after downscale); all images must share one size"
            )
    cameras = _cameras(present, [size for _, _, size in loaded]).scaled(downscale)
    images = np.stack([rgb for rgb, _, _ in loaded])
    alphas = None
    if any(a is not None for _, a, _ in loaded):
        alphas = np.stack([np.ones(rgb.shape[:2], np.float32) if a is None else a for rgb, a, _ in loaded])

    n = len(present)
    test_mask = np.zeros(n, bool)
    if holdout_every:
        test_mask[::holdout_every] = True
    normalisation, up, scene_radius = _normalisation(
        fmt, cameras, present[0].json_path, present[0].meta, bound
    )
    log.info(
        "%s: %d views (%d train, %d test) %dx%d, %s, centre %s, bound %.3g",
        root,
        n,
        n - test_mask.sum(),
        test_mask.sum(),
        images.shape[2],
        images.shape[1],
        fmt,
        np.round(normalisation.center, 3).tolist(),
        1.0 / normalisation.scale,
    )
    return SceneData(
        images=images,
        alphas=alphas,
        cameras=cameras,
        train_idx=np.flatnonzero(~test_mask),
        test_idx=np.flatnonzero(test_mask),
        normalisation=normalisation,
        up=up,
        background=background,
        source=root,
        format=fmt,
        scene_radius=scene_radius,
    )


def load_camera_file(path: str | os.PathLike, width: int | None = None, height: int | None = None) -> Cameras:
    """Cameras from a ``transforms*.json``-style file, or a dataset directory as ``train --data`` takes it,
    whose images may be absent (e.g. a render path, or held-out views of a capture).

    Every listed frame is a camera, with or without its image, in the file's own world coordinates (the
    ones a field trained on it uses), with the intrinsics and distortion of :func:`_cameras`. The file's
    image size is its ``w``/``h`` keys, else the size of the first listed image that exists, else the
    requested size (square when only one is given). ``width`` and/or ``height`` ask for another size: a
    missing one keeps each camera's aspect ratio, and pixel intrinsics are rescaled (``fx, cx`` by
    ``W'/W``, ``fy, cy`` by ``H'/H``; distortion is unitless and unchanged). Names are the image stems,
    or the image paths relative to the dataset (``train_r_0``) where stems repeat. Anything unusable is an
    :class:`InputError`.
    """
    for name, value in (("width", width), ("height", height)):
        if value is not None and not (int(value) == value and value >= 1):
            raise ValueError(f"{name}: expected a positive int, got {value!r}")
    path = Path(path)
    if path.is_dir():
        try:
            root, _, json_paths = _locate(path)
        except InputError:
            raise InputError(f"{path}: is a directory, not a camera file") from None
    elif path.is_file():
        root, json_paths = path.parent, [path]
    else:
        raise InputError(f"{path}: camera file not found")
    frames = [f for jp in json_paths for f in _read_frames(jp, need_images=False)]
    if not frames:
        raise InputError(f"{', '.join(map(str, json_paths))}: no frames listed")
    size = None  # used only by frames without 'w'/'h' keys
    if any(_get(f, "w") is None or _get(f, "h") is None for f in frames):
        image = next((f.image_path for f in frames if f.image_path and f.image_path.is_file()), None)
        if image is not None:
            size = _image_size(image)
        elif width is not None or height is not None:
            size = (width or height, height or width)  # nothing to keep the aspect ratio of: square
        else:
            raise InputError(
                f"{path}: no image size: no 'w'/'h' keys, none of the listed images exists, and no "
                f"width/height was given"
            )
    cameras = _cameras(frames, [size] * len(frames), check_size=False)
    if len(set(cameras.names)) != len(cameras.names):
        cameras.names = [
            f"frame_{f.index}" if f.image_path is None else _relative(f.image_path.with_suffix(""), root)
            for f in frames
        ]
        cameras.names = [n.replace(os.sep, "_").replace("/", "_").lstrip("._") for n in cameras.names]
    if width is None and height is None:
        return cameras
    if width is None:
        width = np.maximum(1, np.round(cameras.width * height / cameras.height)).astype(np.int64)
    if height is None:
        height = np.maximum(1, np.round(cameras.height * width / cameras.width)).astype(np.int64)
    return cameras.resized(width, height)


def _normalisation(fmt: str, cameras: Cameras, json_path: Path, meta: dict, bound: float | None):
    """(Normalisation, up (3,), scene radius) by the per-format rule of the module docstring."""
    if fmt == "nerf-synthetic":
        half = SYNTHETIC_BOUND if bound is None else float(bound)
        return Normalisation(np.zeros(3), 1.0 / half), np.array([0.0, 0.0, 1.0]), half
    center = _focus_point(cameras.c2w)
    distance = float(np.mean(np.linalg.norm(cameras.c2w[:, :3, 3] - center, axis=1)))
    if bound is None and not distance > 0:
        raise InputError(
            f"{json_path}: every camera sits at the point they look at: give the bound explicitly"
        )
    half = NGP_CUBE_FRACTION * distance if bound is None else float(bound)
    up = cameras.c2w[:, :3, 1].mean(axis=0)
    aabb_scale = _number(json_path, "top-level 'aabb_scale'", "aabb_scale", meta.get("aabb_scale", 1))
    return Normalisation(center, 1.0 / half), up / np.linalg.norm(up), half * max(1.0, aabb_scale)


def _locate(path: Path) -> tuple[Path, str, list[Path]]:
    """(dataset root, format, JSON files to read) for a directory or a transforms JSON."""
    if path.is_file():
        root = path.parent
        fmt = "instant-ngp" if path.name == "transforms.json" else "nerf-synthetic"
        return root, fmt, [path]
    if not path.is_dir():
        raise InputError(f"{path}: no such dataset directory or file")
    synthetic = [path / f"transforms_{s}.json" for s in SYNTHETIC_SPLITS]
    synthetic = [p for p in synthetic if p.is_file()]
    if synthetic:
        return path, "nerf-synthetic", synthetic
    if (path / "transforms.json").is_file():
        return path, "instant-ngp", [path / "transforms.json"]
    from .colmap import find_model  # a COLMAP model: SCENE/sparse/0 (or that directory itself)

    model = find_model(path)
    if model is not None:
        return path, "colmap", [model]
    raise InputError(
        f"{path}: not a dataset: expected transforms_train.json (NeRF-synthetic), transforms.json "
        f"(instant-ngp / nerfstudio) or a COLMAP model sparse/0 beside images/"
    )


def _read_frames(json_path: Path, need_images: bool = True) -> list[_Frame]:
    if json_path.is_dir():  # a COLMAP model directory (see _locate), converted as `shellsim poses` does
        from .colmap import model_transforms

        meta, json_path = model_transforms(json_path, need_images)
        return _parse_frames(json_path, meta, need_images)
    try:
        text = json_path.read_text(encoding="utf-8")
    except OSError as err:
        raise InputError(f"{json_path}: cannot read: {err.strerror}") from None
    except UnicodeDecodeError as err:
        raise InputError(
            f"{json_path}: not a UTF-8 text file (byte {err.object[err.start]:#04x} at offset {err.start})"
        ) from None
    if not text.strip():
        raise InputError(f"{json_path}: the file is empty, expected a JSON object with a 'frames' list")
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(f"{json_path}: malformed JSON: {err}") from None
    if not isinstance(meta, dict):
        raise InputError(f"{json_path}: expected a JSON object at the top level")
    if not isinstance(meta.get("frames"), list):
        raise InputError(f"{json_path}: no 'frames' list")
    return _parse_frames(json_path, meta, need_images)


def _parse_frames(json_path: Path, meta: dict, need_images: bool) -> list[_Frame]:
    """The frames of a parsed ``transforms*.json`` dict; errors name ``json_path``."""
    frames = []
    for i, frame in enumerate(meta["frames"]):
        if not isinstance(frame, dict):
            raise InputError(f"{json_path}: frame {i} is not a JSON object")
        where = _frame_label(i, frame)
        for key in ("transform_matrix", "file_path") if need_images else ("transform_matrix",):
            if key not in frame:
                raise InputError(f"{json_path}: {where} has no {key!r}")
        try:
            c2w = camera_pose(frame["transform_matrix"])
        except ValueError as err:
            raise InputError(f"{json_path}: {where}: 'transform_matrix' {err}") from None
        image = _image_path(json_path, where, frame["file_path"]) if "file_path" in frame else None
        frames.append(_Frame(json_path, i, meta, frame, c2w, image))
    return frames


def _frame_label(i: int, frame: dict) -> str:
    """``frame 3 (./train/r_3)``: the index in the file and, when it is a string, the frame's file_path."""
    file_path = frame.get("file_path")
    return f"frame {i}" + (f" ({file_path})" if isinstance(file_path, str) else "")


def camera_pose(value) -> np.ndarray:
    """(4, 4) float64 camera-to-world from a 4x4 or 3x4 nested list, checked to be a rigid motion.

    Both formats store a pose: finite numbers, a last row ``0 0 0 1`` and a rotation part ``R`` with
    ``|R^T R - I| <= POSE_TOLERANCE`` elementwise and ``det R > 0`` (no scale, shear or mirroring: neither
    format defines them, and they would silently distort every ray). Anything else is a ``ValueError``
    saying what is wrong.
    """
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = None
    if m is None or m.shape not in ((4, 4), (3, 4)):
        raise ValueError("must be a 4x4 or 3x4 matrix of numbers")
    if not np.all(np.isfinite(m)):
        raise ValueError("contains NaN or infinity")
    if not np.any(m):
        raise ValueError("is all zeros: not a camera pose")
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"must have the last row 0 0 0 1, got {' '.join(f'{v:g}' for v in m[3])}")
    rot = m[:3, :3]
    if not np.any(rot):
        raise ValueError("has an all-zero rotation part: not a camera pose")
    error = np.abs(rot.T @ rot - np.eye(3)).max()
    if error > POSE_TOLERANCE:
        lengths = ", ".join(f"{v:.4g}" for v in np.linalg.norm(rot, axis=0))
        raise ValueError(
            f"has a rotation part that is not orthonormal (|R^T R - I| = {error:.3g} > {POSE_TOLERANCE:g}; "
            f"column lengths {lengths}): a pose has no scale or shear"
        )
    if np.linalg.det(rot) < 0:
        raise ValueError("has a rotation part with a negative determinant: a mirror image, not a camera pose")
    return m


def _image_path(json_path: Path, where: str, file_path) -> Path:
    """The image of a frame: ``file_path`` relative to the JSON, ``.png`` appended when it has none."""
    if not isinstance(file_path, str):
        raise InputError(f"{json_path}: {where}: 'file_path' must be a string, got {file_path!r}")
    image = json_path.parent / file_path
    if image.suffix == "" or (not image.is_file() and image.with_name(image.name + ".png").is_file()):
        image = image.with_name(image.name + ".png")
    return image


def _get(frame: _Frame, key: str):
    """A per-frame key, falling back to the file-level one (None when neither has it)."""
    return frame.frame[key] if key in frame.frame else frame.meta.get(key)


def _where(frame: _Frame, key: str) -> str:
    """Where ``key`` of ``frame`` comes from: ``frame 3 (./r_3): 'fl_x'`` or ``top-level 'fl_x'``."""
    if key in frame.frame:
        return f"{_frame_label(frame.index, frame.frame)}: {key!r}"
    return f"top-level {key!r}"


def _number(json_path: Path, where: str, key: str, value) -> float:
    """``value`` of the intrinsic ``key`` as a float, checked: ``w``/``h`` positive whole pixels, focal
    lengths and ``aabb_scale`` positive, angles in (0, pi) radians, the rest finite; else an
    :class:`InputError` naming ``where`` (see :func:`_where`)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{json_path}: {where} must be a finite number, got {value!r}")
    if key in ("w", "h") and not (value >= 1 and value == round(value)):
        raise InputError(f"{json_path}: {where} must be a positive whole number of pixels, got {value!r}")
    if key in ("fl_x", "fl_y", "aabb_scale") and not value > 0:
        raise InputError(f"{json_path}: {where} must be positive, got {value!r}")
    if key in ("camera_angle_x", "camera_angle_y") and not 0 < value < math.pi:
        raise InputError(f"{json_path}: {where} must be a field of view in radians in (0, pi), got {value!r}")
    return float(value)


def _cameras(frames: list[_Frame], sizes: list, check_size: bool = True) -> Cameras:
    """Cameras for ``frames`` with intrinsics as in the module doc.

    ``sizes``: per frame the image's (W, H), the default for missing ``w``/``h`` keys (None: keys present).
    ``check_size``: keys that disagree with ``sizes`` are an :class:`InputError`.
    """
    rows = []
    for f, (img_w, img_h) in zip(frames, [s or (None, None) for s in sizes], strict=True):
        where = f" {_frame_label(f.index, f.frame)}:"

        def num(key, default=None, f=f):
            value = _get(f, key)
            return default if value is None else _number(f.json_path, _where(f, key), key, value)

        w, h = num("w", img_w), num("h", img_h)
        if check_size and (round(w), round(h)) != (img_w, img_h):
            raise InputError(
                f"{f.json_path}:{where} 'w' x 'h' = {w:g}x{h:g} but {f.image_path} is {img_w}x{img_h}"
            )
        model = _get(f, "camera_model")
        if model is not None and model not in SUPPORTED_CAMERA_MODELS:
            raise InputError(
                f"{f.json_path}:{where} camera_model {model!r} is not supported "
                f"(only {', '.join(SUPPORTED_CAMERA_MODELS)})"
            )
        if _get(f, "is_fisheye") or num("k3", 0.0) or num("k4", 0.0):
            raise InputError(
                f"{f.json_path}:{where} fisheye / k3 k4 distortion is not supported (only k1 k2 p1 p2)"
            )
        fx = num("fl_x")
        if fx is None:
            angle = num("camera_angle_x")
            if angle is None:
                raise InputError(
                    f"{f.json_path}: no focal length: neither the top level nor{where[:-1]} has 'fl_x' or "
                    "'camera_angle_x'"
                )
            fx = 0.5 * w / math.tan(0.5 * angle)
        fy = num("fl_y")
        if fy is None:
            angle = num("camera_angle_y")
            fy = fx if angle is None else 0.5 * h / math.tan(0.5 * angle)
        dist = [num(k, 0.0) for k in ("k1", "k2", "p1", "p2")]
        rows.append((f.c2w, fx, fy, num("cx", 0.5 * w), num("cy", 0.5 * h), round(w), round(h), dist))
    c2w, fx, fy, cx, cy, width, height, dist = zip(*rows, strict=True)
    return Cameras(
        c2w=np.stack(c2w),
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        width=width,
        height=height,
        distortion=np.array(dist),
        names=[f"frame_{f.index}" if f.image_path is None else f.image_path.stem for f in frames],
    )


def _image_size(path: Path) -> tuple[int, int]:
    try:
        with Image.open(path) as im:
            return im.size
    except (OSError, UnidentifiedImageError) as err:
        raise InputError(f"{path}: cannot read image: {err}") from err


def _load_image(path: Path, downscale: float, background: np.ndarray):
    """Decode, composite on ``background`` and area-downscale one image.

    Returns rgb (h, w, 3) float32, alpha (h, w) float32 or None, and the full-resolution size (W, H).
    """
    try:
        with Image.open(path) as im:
            if im.mode in ("I", "F"):
                raise InputError(f"{path}: 32-bit {im.mode!r} images are not supported (only 8 or 16 bits)")
            has_alpha = im.mode in ("RGBA", "LA", "PA", "RGBa") or "transparency" in im.info
            if im.mode.startswith("I;16"):  # 16-bit grey: convert() would clip it to 8 bits
                pixels, peak = np.repeat(np.asarray(im)[:, :, None], 3, axis=2), 65535
            else:
                pixels, peak = np.asarray(im.convert("RGBA" if has_alpha else "RGB")), 255
    except (OSError, UnidentifiedImageError) as err:
        raise InputError(f"{path}: cannot read image: {err}") from None
    full = (pixels.shape[1], pixels.shape[0])
    planes = np.empty((pixels.shape[2], full[1], full[0]), np.float32)  # channels first: fast inner loops
    np.multiply(pixels.transpose(2, 0, 1), np.float32(1 / peak), out=planes)
    if has_alpha:  # straight (unassociated) alpha as PNG stores it: rgb a + bg (1 - a) = bg + a (rgb - bg)
        bg = background[:, None, None]
        planes[:3] -= bg
        planes[:3] *= planes[3]
        planes[:3] += bg
    size = (int(scaled_size(full[0], downscale)), int(scaled_size(full[1], downscale)))
    if size != full:  # the area filter commutes with compositing: both are linear in rgb and alpha
        planes = _area_resize(planes, size)
    rgb = np.ascontiguousarray(planes[:3].transpose(1, 2, 0))
    return rgb, (planes[3] if has_alpha else None), full


def _area_resize(planes: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(C, H, W) float32 -> (C, h, w) float32 with a box (area) filter; ``size`` is (w, h)."""
    (w, h), (c, H, W) = size, planes.shape
    if H % h == 0 and W % w == 0:  # integer factors: exact block means
        rows = planes.reshape(c, h, H // h, W).sum(axis=2)
        return rows.reshape(c, h, w, W // w).sum(axis=3) / np.float32((H // h) * (W // w))
    resized = [np.asarray(Image.fromarray(p).resize(size, Image.Resampling.BOX)) for p in planes]
    return np.stack(resized).astype(np.float32)


def _focus_point(c2w: np.ndarray) -> np.ndarray:
    """(3,) point minimising the summed squared distance to the optical axes of ``c2w`` (N, 4, 4).

    Solves ``sum_i (I - d_i d_i^T) (c - o_i) = 0`` for camera centres ``o_i`` and view directions ``d_i``.
    """
    origins, dirs = c2w[:, :3, 3], -c2w[:, :3, 2]
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    proj = np.eye(3) - dirs[:, :, None] * dirs[:, None, :]
    a, b = proj.sum(axis=0), np.einsum("nij,nj->i", proj, origins)
    center, _, rank, _ = np.linalg.lstsq(a, b, rcond=1e-9)
    if rank < 3:
        log.warning("camera axes are (nearly) parallel: the scene centre along them is undetermined")
    return center


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)
