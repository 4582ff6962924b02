"""Deterministic writers for the nerfstudio-data and Blender (NeRF-synthetic) folder layouts.

nerfstudio-data (presets ``orbit``, ``forward``, ``facing``; dataparser ``nerfstudio-data``)::

    OUTPUT/
      transforms.json        intrinsics, frames (poses, image + depth paths), splits, ply path
      images/frame_00000.png 8-bit RGB
      depths/frame_00000.npy float32 (H, W) z-depth along the camera's -Z, world units, 0 = sky
      sparse_pc.ply          binary PLY seed points: float x, y, z; uchar red, green, blue
      scene.json             preset, seed, resolution, scene centre and radius, ...

Blender (preset ``object``; dataparser ``blender-data``)::

    OUTPUT/
      transforms_train.json  camera_angle_x, frames: file_path "./train/r_0", transform_matrix
      transforms_val.json    (and transforms_test.json) the same for the val and test views
      train/r_0.png          8-bit RGBA, straight alpha, background transparent (alpha 0)
      val/r_0.png, test/r_0.png
      depths/train/r_0.npy   float32 (H, W) z-depth, world units, 0 = background
      scene.json

The same inputs give byte-identical files: PNGs (:func:`stealth_ns.images.io.save_png`) carry no
timestamps, JSON has sorted keys and floats rounded to a fixed number of decimals.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stealth_ns.foundation.file_manifest import Manifest, files_under, read_manifest, remove_owned
from stealth_ns.foundation.file_manifest import foreign_files as foreign_files_of
from stealth_ns.foundation.file_manifest import write_manifest as record_files
from stealth_ns.images.io import to_uint8

BLENDER_SPLITS = ("train", "val", "test")
GENERATED = (
    "images",
    "depths",
    "transforms.json",
    "sparse_pc.ply",
    "scene.json",
    *BLENDER_SPLITS,
    *(f"transforms_{split}.json" for split in BLENDER_SPLITS),
)
"""Top-level entries of the output folder the generator writes (of any format)."""
MANIFEST = ".stealth-ns-scene.json"
"""The generator's record of the files it wrote (relative paths and SHA-256): ``--overwrite``
removes only those, unchanged, and refuses a folder holding anything else under :data:`GENERATED`."""


def image_path(i: int) -> str:
    """Relative path of frame ``i``'s image."""
    return f"images/frame_{i:05d}.png"


def depth_path(i: int) -> str:
    """Relative path of frame ``i``'s depth map."""
    return f"depths/frame_{i:05d}.npy"


def blender_frame_path(split: str, k: int) -> str:
    """``file_path`` of the ``k``-th view of ``split`` in a Blender transforms file (no extension)."""
    return f"./{split}/r_{k}"


def blender_depth_path(split: str, k: int) -> str:
    """Relative path of the ``k``-th ``split`` view's depth map in the Blender layout."""
    return f"depths/{split}/r_{k}.npy"


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """Write points ``xyz`` (N, 3) world units with colours ``rgb`` (N, 3), uint8 or float in [0, 1]
    (:func:`~stealth_ns.images.io.to_uint8`), as binary little-endian PLY (float32 position, uchar
    colour), readable by open3d."""
    n = xyz.shape[0]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment stealth-ns procedural seed points\n"
        f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    rec = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    col = to_uint8(rgb)
    rec["r"], rec["g"], rec["b"] = col[:, 0], col[:, 1], col[:, 2]
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(rec.tobytes())


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a PLY written by :func:`write_ply`: xyz (N, 3) float32 and rgb (N, 3) uint8."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    n = int(
        next(ln for ln in data[:end].decode().splitlines() if ln.startswith("element vertex")).split()[-1]
    )
    rec = np.frombuffer(data[end:], dtype=[("p", "<f4", 3), ("c", "u1", 3)], count=n)
    return rec["p"].copy(), rec["c"].copy()


def round_floats(obj, decimals: int = 8):
    """Recursively round floats (and numpy scalars/arrays) in ``obj`` to ``decimals`` places."""
    if isinstance(obj, dict):
        return {k: round_floats(v, decimals) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [round_floats(v, decimals) for v in obj]
    if isinstance(obj, np.ndarray):
        return round_floats(obj.tolist(), decimals)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = round(float(obj), decimals)
        return 0.0 if v == 0 else v  # no "-0.0"
    return obj


def write_json(path: Path, obj: dict) -> None:
    """Write ``obj`` as indented JSON with sorted keys and rounded floats."""
    text = json.dumps(round_floats(obj), indent=2, sort_keys=True)
    Path(path).write_text(text + "\n", encoding="utf-8")


def _manifest(output: Path) -> tuple[Manifest, list[str]]:
    """The generator's manifest in ``output`` and the files under its :data:`GENERATED` entries."""
    return read_manifest(output / MANIFEST), files_under(output, GENERATED)


def foreign_files(output: Path) -> list[str]:
    """Files under the generator's entries of ``output`` that the manifest does not record as
    written by the generator (or that changed since): ``--overwrite`` must not touch them."""
    manifest, present = _manifest(output)
    return foreign_files_of(output, manifest, present)


def write_manifest(output: Path, files: list[str], hashes: bool) -> None:
    """Record ``files`` (relative paths) as written by the generator; with ``hashes`` their SHA-256
    (after writing), else None (before writing: a run cut short may still remove them)."""
    # the manifest's label keeps the package's first name: scenes written before and after read the same
    record_files(output / MANIFEST, output, files, "stealth_ns.scenes", hashes)


def clear_recorded(output: Path) -> None:
    """Remove the files the manifest records (call :func:`foreign_files` first), then the folders
    they leave empty, then the manifest; nothing else is touched."""
    manifest, present = _manifest(output)
    remove_owned(output, manifest, present)
    (output / MANIFEST).unlink(missing_ok=True)


def transforms_dict(
    intr, c2w: np.ndarray, train: list[int], test: list[int], with_depth: bool = True
) -> dict:
    """The ``transforms.json`` content for poses ``c2w`` (V, 4, 4) and intrinsics ``intr``
    (:class:`~stealth_ns.scene_generator.render.Intrinsics`); ``val_filenames`` equals ``test_filenames``
    (nerfstudio's datamanagers ask for split "val" during training)."""
    frames = []
    for i, m in enumerate(c2w):
        frame = {"file_path": image_path(i), "transform_matrix": m}
        if with_depth:
            frame["depth_file_path"] = depth_path(i)
        frames.append(frame)
    test_names = [image_path(i) for i in test]
    return {
        "camera_model": "OPENCV",
        "fl_x": intr.fl_x,
        "fl_y": intr.fl_y,
        "cx": intr.cx,
        "cy": intr.cy,
        "w": intr.width,
        "h": intr.height,
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "frames": frames,
        "train_filenames": [image_path(i) for i in train],
        "val_filenames": test_names,
        "test_filenames": test_names,
        "ply_file_path": "sparse_pc.ply",
    }


def blender_transforms_dict(camera_angle_x: float, c2w: np.ndarray, split: str) -> dict:
    """``transforms_{split}.json`` content: ``camera_angle_x`` (radians) and one frame per pose of
    ``c2w`` (V, 4, 4), OpenGL camera-to-world, with its image (``file_path``, no extension, as in
    NeRF-synthetic) and depth map (``depth_file_path``, ignored by nerfstudio's Blender parser)."""
    return {
        "camera_angle_x": camera_angle_x,
        "frames": [
            {
                "file_path": blender_frame_path(split, k),
                "depth_file_path": blender_depth_path(split, k),
                "transform_matrix": m,
            }
            for k, m in enumerate(c2w)
        ],
    }
