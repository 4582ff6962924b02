"""Which dataset a run was trained on: a content hash of its images and its cameras.

``stealth-ns report`` (and ``bench``) compare a poisoned run with a clean one by rendering both
from the poisoned run's cameras and scoring both against its images, which is meaningful only
when both were trained on the same dataset. Image names alone do not tell (every generated scene
has ``frame_00000.png``...), so a run records, when training starts, a fingerprint of its training
split in ``RUN/dataset.json`` (:func:`record_fingerprint`, called by the stealth pipeline, clean or
attacked):

* ``images``: SHA-256 over the image file names and the SHA-256 of each file's bytes, in order;
* ``poses``: SHA-256 over the cameras as nerfstudio's dataparser returns them (normalised
  camera-to-world matrices, fx, fy, cx, cy, width, height, camera type), rounded to 1e-4.

Runs without the file (trained before it existed, or by another method) get it recomputed from the
dataset when loaded.

Which *model* a run holds is told by its Gaussians, not by its path: :func:`same_points` finds a copy of a
run, or a PLY exported from it, however it is named (``stealth-ns report`` refuses to compare a run with
itself).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.foundation.json_io import write_json_atomic

#: Written into the run folder (next to config.yml) when training starts.
FINGERPRINT_FILE = "dataset.json"
#: Bumped when the recipe changes; a recorded fingerprint of another version is recomputed.
FINGERPRINT_VERSION = 1
#: Two models are one when every Gaussian centre of each lies this close (scene units: nerfstudio's
#: normalised frame, the cameras within [-1, 1]) to one of the other; exporting a model as a float32 PLY
#: and loading it back moves them by ~1e-7, training one step moves them by more.
SAME_MODEL_TOLERANCE = 1e-5


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def camera_array(cameras: Any) -> np.ndarray:
    """``[N, 19]`` float64: flattened c2w [3, 4], fx, fy, cx, cy, width, height, camera type."""
    c2w = cameras.camera_to_worlds.detach().cpu().double().numpy().reshape(len(cameras), -1)
    intr = [
        getattr(cameras, k).detach().cpu().double().numpy().reshape(len(cameras), -1)[:, :1]
        for k in ("fx", "fy", "cx", "cy", "width", "height", "camera_type")
    ]
    return np.concatenate([c2w, *intr], axis=1)


def dataset_fingerprint(outputs: Any) -> dict[str, Any]:
    """The fingerprint of one split's ``DataparserOutputs`` (see the module docstring)."""
    images = hashlib.sha256()
    for path in outputs.image_filenames:
        images.update(Path(path).name.encode() + b"\0" + file_sha256(Path(path)).encode() + b"\n")
    cams = np.round(camera_array(outputs.cameras), 4) + 0.0  # + 0.0: -0.0 -> 0.0
    poses = hashlib.sha256(np.ascontiguousarray(cams, dtype="<f8").tobytes())
    return {
        "version": FINGERPRINT_VERSION,
        "n_images": len(outputs.image_filenames),
        "images": images.hexdigest(),
        "poses": poses.hexdigest(),
    }


def record_fingerprint(run_dir: Path, train: dict[str, Any], data: Path | str | None = None) -> Path:
    """Write ``run_dir/dataset.json`` with ``train``, the training split's :func:`dataset_fingerprint`."""
    path = Path(run_dir) / FINGERPRINT_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"data": None if data is None else str(data), "train": train}
    write_json_atomic(path, record)
    return path


def recorded_fingerprint(run_dir: Path) -> dict[str, Any] | None:
    """The training split's fingerprint recorded in ``run_dir/dataset.json``, if any (and current)."""
    try:
        record = json.loads((Path(run_dir) / FINGERPRINT_FILE).read_text())
        train = record["train"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(train, dict) or train.get("version") != FINGERPRINT_VERSION:
        return None
    if not all(isinstance(train.get(k), str) for k in ("images", "poses")):
        return None
    return train


def fingerprint_differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """``["images", "poses"]`` or a part of it: what differs between two fingerprints."""
    diff = []
    if a.get("images") != b.get("images") or a.get("n_images") != b.get("n_images"):
        diff.append("images")
    if a.get("poses") != b.get("poses") or a.get("n_images") != b.get("n_images"):
        diff.append("poses")
    return diff


def same_points(a: np.ndarray, b: np.ndarray, tolerance: float = SAME_MODEL_TOLERANCE) -> bool:
    """Whether the points ``a`` and ``b`` (``[N, 3]``, e.g. two models' Gaussian centres; rows with a NaN
    or an infinity left out, as a PLY export drops them) are the same up to ``tolerance``: as many, and
    each of either within ``tolerance`` of one of the other, in whatever order."""
    a, b = (np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in (a, b))
    a, b = a[np.isfinite(a).all(axis=1)], b[np.isfinite(b).all(axis=1)]
    if a.shape != b.shape:
        return False
    if len(a) == 0 or np.allclose(a, b, rtol=0.0, atol=tolerance):
        return True
    from scipy.spatial import cKDTree

    for points, others in ((a, b), (b, a)):
        distances, _ = cKDTree(others).query(points, distance_upper_bound=tolerance)
        if not np.isfinite(distances).all():
            return False
    return True
