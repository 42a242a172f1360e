"""Recorded RGB-D datasets on disk, read as a list of frames (colour path, depth path, stamp,
camera-to-world pose where the dataset has one) and the camera's intrinsics.

Layouts (``detect`` tells them apart; ``--format`` names one):

- ``tum``: TUM RGB-D folders: ``rgb.txt`` and ``depth.txt`` ("stamp path" lines, ``#``
  comments), optional ``groundtruth.txt`` (``t tx ty tz qx qy qz qw``: the colour optical frame
  in the world) and ``associations.txt``; depth ÷ 5000 = m. Colour and depth are associated by
  the nearest stamp (within ``max_dt``), poses by the nearest stamp too. TUM folders do not
  store intrinsics: an ``intrinsics.txt`` (``w h fx fy cx cy [depth_scale]``) is read where
  present, else ``--intrinsics`` is needed.
- ``7scenes``: the 7-Scenes / 3DMatch layout: ``frame-NNNNNN.color.(jpg|png)``,
  ``frame-NNNNNN.depth.png`` (mm, 65535 = none), ``frame-NNNNNN.pose.txt`` (4×4
  camera-to-world), ``camera-intrinsics.txt`` (3×3 K). Frames are 1/30 s apart (the Kinect's
  rate; the layout stores no stamps).
- ``folder``: a plain folder of colour and depth images paired by name (``*color*``/``*rgb*``
  and ``*depth*`` with the same number in them), with ``--intrinsics`` and ``--depth-scale``.

Nothing here decodes an image or talks to Zenoh: ``frames.py`` reads the images.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FORMATS = ("tum", "7scenes", "folder")
#: metres per depth unit: TUM (÷ 5000), 7-Scenes (mm)
TUM_DEPTH_SCALE = 1 / 5000
SEVEN_SCENES_DEPTH_SCALE = 1e-3
#: s between 7-Scenes frames (30 Hz; the layout stores no stamps)
SEVEN_SCENES_PERIOD = 1 / 30


class DatasetError(ValueError):
    """A dataset folder that cannot be read: says which file and why."""


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass
class Recording:
    """What a dataset holds: its frames in time order and how to read them."""

    format: str
    root: Path
    stamps: list[float]
    colour: list[Path]
    depth: list[Path]
    #: camera-to-world (optical frame: x right, y down, z forward) per frame; None: no poses
    poses: list[np.ndarray] | None
    intrinsics: Intrinsics | None
    depth_scale: float
    #: 16-bit depth values that mean "no return" besides 0
    invalid_depth: tuple[int, ...] = ()
    skipped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.stamps)


def detect(root: Path) -> str:
    """The layout of ``root``: ``tum``, ``7scenes`` or ``folder`` (DatasetError: none)."""
    if not root.is_dir():
        raise DatasetError(f"{root}: not a folder")
    if (root / "rgb.txt").is_file() and (root / "depth.txt").is_file():
        return "tum"
    if any(root.glob("frame-*.depth.png")):
        return "7scenes"
    if _pairs_by_name(root):
        return "folder"
    raise DatasetError(
        f"{root}: no dataset layout found (TUM: rgb.txt and depth.txt; 7-Scenes: "
        "frame-NNNNNN.depth.png; a folder: *color*/*rgb* and *depth* images with the same number)"
    )


def read(
    root: Path,
    fmt: str | None = None,
    intrinsics: Intrinsics | None = None,
    depth_scale: float | None = None,
    max_dt: float = 0.02,
) -> Recording:
    """The recording in ``root`` (its layout ``fmt``, or detected); ``intrinsics`` and
    ``depth_scale`` replace what the dataset says (or supply what it does not)."""
    fmt = fmt or detect(root)
    if fmt == "tum":
        rec = _tum(root, max_dt)
    elif fmt == "7scenes":
        rec = _seven_scenes(root)
    elif fmt == "folder":
        rec = _folder(root)
    else:
        raise DatasetError(f"unknown format {fmt!r} (known: {', '.join(FORMATS)})")
    if intrinsics is not None:
        rec.intrinsics = intrinsics
    if depth_scale is not None:
        rec.depth_scale = depth_scale
    if rec.intrinsics is None:
        raise DatasetError(
            f"{root}: the {fmt} layout stores no intrinsics here: give --intrinsics fx,fy,cx,cy"
        )
    if not len(rec):
        raise DatasetError(f"{root}: no frames")
    return rec


# -- TUM RGB-D ---------------------------------------------------------------------------------


def _stamped_lines(path: Path) -> list[list[str]]:
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            float(parts[0])
        except ValueError:
            raise DatasetError(f"{path}:{n}: not 'stamp ...': {line[:60]!r}") from None
        rows.append(parts)
    return rows


def _nearest(stamps: np.ndarray, t: float) -> int:
    i = int(np.searchsorted(stamps, t))
    if i == 0:
        return 0
    if i == len(stamps):
        return len(stamps) - 1
    return i if stamps[i] - t < t - stamps[i - 1] else i - 1


def _tum(root: Path, max_dt: float) -> Recording:
    rgb = _stamped_lines(root / "rgb.txt")
    depth = _stamped_lines(root / "depth.txt")
    d_stamps = np.array([float(r[0]) for r in depth])
    order = np.argsort(d_stamps)
    d_stamps = d_stamps[order]
    depth = [depth[i] for i in order]
    stamps, colour, depths, skipped = [], [], [], 0
    for row in sorted(rgb, key=lambda r: float(r[0])):
        t = float(row[0])
        j = _nearest(d_stamps, t)
        if abs(d_stamps[j] - t) > max_dt:
            skipped += 1
            continue
        stamps.append(t)
        colour.append(root / row[1])
        depths.append(root / depth[j][1])
    poses = None
    gt = root / "groundtruth.txt"
    if gt.is_file():
        rows = _stamped_lines(gt)
        g_stamps = np.array([float(r[0]) for r in rows])
        poses = []
        for t in stamps:
            r = rows[_nearest(g_stamps, t)]
            if len(r) != 8:
                raise DatasetError(f"{gt}: expected 't tx ty tz qx qy qz qw', got {len(r)} fields")
            poses.append(_pose(*map(float, r[1:])))
    intrinsics, scale = None, TUM_DEPTH_SCALE
    if (root / "intrinsics.txt").is_file():
        intrinsics, given = _intrinsics_line(root / "intrinsics.txt")
        if given is not None:
            scale = 1 / given
    return Recording("tum", root, stamps, colour, depths, poses, intrinsics, scale,
                     skipped={"no depth within max_dt": skipped} if skipped else {})  # fmt: skip


def _pose(tx, ty, tz, qx, qy, qz, qw) -> np.ndarray:
    q = np.array([qw, qx, qy, qz])
    q /= np.linalg.norm(q)
    w, x, y, z = q
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, 3] = tx, ty, tz
    return T


def nearest_rigid(T: np.ndarray, source: Path) -> np.ndarray:
    """``T`` with its rotation made orthonormal (the nearest rotation: SVD). Reference poses
    written as text (7-Scenes' KinectFusion ones) are off by up to ~1e-3; more than 1e-2 is
    no rotation at all."""
    U, S, Vt = np.linalg.svd(T[:3, :3])
    if np.abs(S - 1).max() > 1e-2 or np.linalg.det(U @ Vt) < 0:
        raise DatasetError(f"{source}: its 3×3 part is no rotation (singular values {S})")
    out = np.array(T, float)
    out[:3, :3] = U @ Vt
    out[3] = [0.0, 0.0, 0.0, 1.0]
    return out


def _intrinsics_line(path: Path) -> tuple[Intrinsics, float | None]:
    """``w h fx fy cx cy [depth_scale]``: the first line that is not a comment."""
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        v = line.split()
        if len(v) not in (6, 7):
            raise DatasetError(f"{path}: expected 'w h fx fy cx cy [depth_scale]', got {line!r}")
        w, h, fx, fy, cx, cy = int(v[0]), int(v[1]), *map(float, v[2:6])
        return Intrinsics(w, h, fx, fy, cx, cy), float(v[6]) if len(v) == 7 else None
    raise DatasetError(f"{path}: no intrinsics line")


# -- 7-Scenes / 3DMatch ------------------------------------------------------------------------

_FRAME = re.compile(r"frame-(\d+)\.depth\.png$")


def _seven_scenes(root: Path) -> Recording:
    numbers = sorted(int(m.group(1)) for p in root.iterdir() if (m := _FRAME.match(p.name)))
    colour, depth, poses, stamps = [], [], [], []
    missing_pose = 0
    for n in numbers:
        stem = root / f"frame-{n:06d}"
        c = next((p for p in (stem.with_suffix(".color.jpg"), stem.with_suffix(".color.png"))
                  if p.is_file()), None)  # fmt: skip
        if c is None:
            raise DatasetError(f"{stem}.depth.png has no colour image (.color.jpg or .color.png)")
        pose_file = stem.with_suffix(".pose.txt")
        if pose_file.is_file():
            T = np.loadtxt(pose_file)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise DatasetError(f"{pose_file}: not a finite 4×4 matrix")
            poses.append(nearest_rigid(T, pose_file))
        else:
            missing_pose += 1
        colour.append(c)
        depth.append(stem.with_suffix(".depth.png"))
        stamps.append(n * SEVEN_SCENES_PERIOD)
    if missing_pose and missing_pose != len(numbers):
        raise DatasetError(f"{root}: {missing_pose} of {len(numbers)} frames have no .pose.txt")
    k_file = root / "camera-intrinsics.txt"
    intrinsics = None
    if k_file.is_file():
        K = np.loadtxt(k_file)
        if K.shape != (3, 3):
            raise DatasetError(f"{k_file}: not a 3×3 K")
        # the layout gives no image size: the depth images' (read by frames.py), 640×480 here
        intrinsics = Intrinsics(0, 0, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                                float(K[1, 2]))  # fmt: skip
    return Recording("7scenes", root, stamps, colour, depth, poses if poses else None,
                     intrinsics, SEVEN_SCENES_DEPTH_SCALE, invalid_depth=(65535,))  # fmt: skip


# -- a plain folder ----------------------------------------------------------------------------

_NUMBER = re.compile(r"(\d+)")
_IMAGE = (".png", ".jpg", ".jpeg")


def _pairs_by_name(root: Path) -> list[tuple[int, Path, Path]]:
    colour, depth = {}, {}
    for p in root.rglob("*"):
        if p.suffix.lower() not in _IMAGE:
            continue
        name = p.name.lower()
        numbers = _NUMBER.findall(p.name)
        if not numbers:
            continue
        n = int(numbers[-1])
        if "depth" in name or p.parent.name.lower() == "depth":
            depth[n] = p
        elif any(k in name for k in ("color", "colour", "rgb")) or p.parent.name.lower() in (
            "rgb", "color", "colour"):  # fmt: skip
            colour[n] = p
    return [(n, colour[n], depth[n]) for n in sorted(colour.keys() & depth.keys())]


def _folder(root: Path) -> Recording:
    pairs = _pairs_by_name(root)
    return Recording("folder", root, [n * SEVEN_SCENES_PERIOD for n, _, _ in pairs],
                     [c for _, c, _ in pairs], [d for _, _, d in pairs], None, None,
                     SEVEN_SCENES_DEPTH_SCALE)  # fmt: skip
