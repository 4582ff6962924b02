"""Dataset folders made from a generated scene, for tests of the readers of users' datasets."""

from __future__ import annotations

import json
import shutil
from pathlib import Path


def colmap_folder(scene: Path, out: Path, xyz=None) -> Path:
    """The scene as a COLMAP folder (``images/``, ``sparse/0``) written by pycolmap, with ``xyz`` (default:
    the scene's seed points) as points3D."""
    import numpy as np
    import pycolmap

    from stealth_ns.scene_generator.writer import read_ply

    meta = json.loads((scene / "transforms.json").read_text())
    rec = pycolmap.Reconstruction()
    params = [meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]]
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(camera_id=1, model="PINHOLE", width=meta["w"], height=meta["h"], params=params)
    )
    (out / "images").mkdir(parents=True)
    for image_id, frame in enumerate(meta["frames"], start=1):
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
        name = Path(frame["file_path"]).name
        shutil.copy2(scene / frame["file_path"], out / "images" / name)
        image = pycolmap.Image(name=name, camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.linalg.inv(c2w)[:3, :4]))
    points = read_ply(scene / meta["ply_file_path"])[0] if xyz is None else xyz
    for p in np.asarray(points, dtype=np.float64).reshape(-1, 3):
        rec.add_point3D(p, pycolmap.Track(), np.array([128, 128, 128], dtype=np.uint8))
    (out / "sparse" / "0").mkdir(parents=True)
    rec.write_binary(str(out / "sparse" / "0"))
    return out
