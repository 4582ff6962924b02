"""The training split of a dataset folder as nerfstudio's dataparser gives it (cameras, seed points),
with one-line errors for what the protocol cannot use.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from stealth_ns.datasets.source import COLMAP_DIRS
from stealth_ns.foundation.errors import StealthNSError

if TYPE_CHECKING:
    pass


Format = Literal["nerfstudio-data", "colmap"]


def detect_format(data: Path) -> tuple[Format, Path]:
    """The dataparser for a dataset folder: ``("nerfstudio-data", folder or json)`` or ``("colmap", rel)``
    with ``rel`` the COLMAP reconstruction folder relative to ``data``, looked for in the order the bench
    and the poisoned copies use (:data:`~stealth_ns.datasets.source.COLMAP_DIRS`: a folder with two
    models is ranked on the one that is attacked). StealthNSError otherwise."""
    data = Path(data)
    if not data.exists():
        raise StealthNSError(f"dataset {data} does not exist")
    if data.is_file():
        if data.suffix == ".json":
            return "nerfstudio-data", data
        raise StealthNSError(f"dataset {data} is a file; give the dataset folder (or its transforms.json)")
    if (data / "transforms.json").is_file():
        return "nerfstudio-data", data
    for rel in COLMAP_DIRS:
        if any((data / rel / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return "colmap", Path(rel)
    if any((data / f"transforms_{s}.json").is_file() for s in ("train", "val", "test")):
        raise StealthNSError(
            f"{data} is a blender-format dataset without a seed point cloud: the KDE difficulty protocol "
            "needs seed points (nerfstudio-data with ply_file_path, or a COLMAP reconstruction); "
            f"triangulate them with `stealth-ns seed-points --data {data}` and rank the seeded copy"
        )
    raise StealthNSError(
        f"{data} has no transforms.json (nerfstudio-data) and no COLMAP reconstruction "
        f"({', '.join(r + '/cameras.bin' for r in COLMAP_DIRS)})"
    )


def _check_seed_points(json_path: Path) -> None:
    """Refuse a transforms.json without a readable ``ply_file_path`` (nerfstudio would fall back to random
    points, or ask an interactive question when a colmap/ folder is present)."""
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise StealthNSError(f"cannot read {json_path}: {err}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise StealthNSError(f"{json_path} is not a nerfstudio transforms.json (no 'frames' list)")
    ply = meta.get("ply_file_path")
    if not ply:
        raise StealthNSError(
            f"{json_path} has no ply_file_path: the KDE difficulty protocol needs the scene's seed points; "
            f"triangulate them with `stealth-ns seed-points --data {json_path.parent}`"
        )
    if not (json_path.parent / ply).is_file():
        raise StealthNSError(f"seed point file {json_path.parent / ply} (ply_file_path) does not exist")
    _check_frame_poses(json_path, meta["frames"])


def _check_frame_poses(json_path: Path, frames: list[Any]) -> None:
    """Refuse a frame whose transform_matrix is not a 4x4 matrix of finite numbers, naming it: one NaN
    turns every pose NaN in nerfstudio's orientation step (and the seed points with them)."""
    for i, frame in enumerate(frames):
        name = frame.get("file_path", f"#{i}") if isinstance(frame, dict) else f"#{i}"
        try:
            matrix = np.asarray(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, KeyError, ValueError):
            raise StealthNSError(
                f"{json_path}: frame {i} ({name}) has no transform_matrix of numbers"
            ) from None
        if matrix.shape != (4, 4):
            raise StealthNSError(
                f"{json_path}: the transform_matrix of frame {i} ({name}) is {matrix.shape}, not 4x4"
            )
        if not np.all(np.isfinite(matrix)):
            raise StealthNSError(
                f"{json_path}: the camera pose (transform_matrix) of frame {i} ({name}) is not finite "
                "(NaN or infinity)"
            )


def load_train_split(data: Path) -> tuple[Any, np.ndarray, str]:
    """Training cameras, seed points ``[P, 3]`` and dataparser name, from nerfstudio's dataparser."""
    fmt, where = detect_format(data)
    if fmt == "nerfstudio-data":
        from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

        _check_seed_points(where if where.suffix == ".json" else where / "transforms.json")
        # downscale_factor=1: poses only, no image is opened (the FOV does not depend on the downscale).
        config: Any = NerfstudioDataParserConfig(data=where, load_3D_points=True, downscale_factor=1)
    else:
        from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig

        # downscale_factor=1 also keeps the parser from offering to downscale images interactively.
        config = ColmapDataParserConfig(data=data, colmap_path=where, load_3D_points=True, downscale_factor=1)
    from nerfstudio.utils.rich_utils import CONSOLE

    quiet = CONSOLE.quiet
    CONSOLE.quiet = True  # the parser's progress notes ("overriding train_indices ...") would bury the table
    try:
        outputs = config.setup().get_dataparser_outputs(split="train")
    except (AssertionError, ValueError, KeyError, IndexError, RuntimeError, OSError) as err:
        raise StealthNSError(f"nerfstudio's {fmt} dataparser cannot read {data}: {err}") from None
    finally:
        CONSOLE.quiet = quiet
    c2w = outputs.cameras.camera_to_worlds.reshape(len(outputs.image_filenames), -1)
    bad = np.flatnonzero(~np.all(np.isfinite(c2w.double().numpy()), axis=1))
    if len(bad):  # a COLMAP model (nerfstudio-data frames are checked before parsing)
        raise StealthNSError(
            f"{data}: the camera pose of {Path(outputs.image_filenames[bad[0]]).name} is not finite "
            f"(NaN or infinity) after nerfstudio's {fmt} dataparser ({len(bad)} such views)"
        )
    points = outputs.metadata.get("points3D_xyz")
    if points is None or len(points) == 0:
        raise StealthNSError(f"{data} has no seed points: the KDE difficulty protocol needs a point cloud")
    return outputs, np.asarray(points, dtype=np.float64).reshape(-1, 3), fmt
