"""The scan at the size people shoot: a ~1M-Gaussian model of a 1-MP, 100-view scene, scanned and timed.

Reproduces docs/design/scan.md "At 1 MP" (issue 58, item 5)::

    .venv/bin/python scripts/scan_at_scale.py --output /tmp/scale

1. ``stealth-ns make-scene --preset orbit --views 100`` at ``--resolution`` / ``--upscale`` (288x216),
   then its images and depth maps enlarged ``--upscale`` times (bilinear, nearest) and its intrinsics
   scaled into a 1152x864 dataset whose 100 views are all training views (rendering 100 procedural
   views at 1 MP takes ~40 min on 2 cores; the scan's cost depends on the image size, the views and
   the Gaussians, not on the photos' detail); skipped when the folder already holds the scene;
2. a clean model: every pixel of ``--source-views`` evenly spaced views back-projected with its depth and
   colour into the dataset's frame, ``--gaussians`` of them drawn at random (``--seed``), each an
   isotropic Gaussian of 1.5 pixel footprints, opacity 0.88, SH degree 3 (zero above degree 0);
3. ``stealth-ns scan`` on it under ``/usr/bin/time -v``; prints the scan's own timings (scan.json) and
   the wall time and peak RSS.

Time it alone: two OpenMP programs on two cores slow each other far more than twice.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from skimage.transform import resize

from stealth_ns.gaussians.ply import REST_COUNTS, GaussianCloud, write_gaussian_ply
from stealth_ns.gaussians.quantisation import dc_of_colour
from stealth_ns.images.io import read_image, save_image, to_float32

FOOTPRINTS = 1.5
OPACITY = 0.88


def _tool(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def make_scene(scene: Path, resolution: str, views: int, upscale: int) -> None:
    if (scene / "transforms.json").is_file():
        print(f"scene: reusing {scene}")
        return
    width, height = (int(x) for x in resolution.split("x"))
    small = scene.with_name(scene.name + "-small")
    if not (small / "transforms.json").is_file():
        cmd = [_tool("stealth-ns"), "make-scene", "--preset", "orbit", "--views", str(views)]
        subprocess.run(
            [*cmd, "--resolution", f"{width // upscale}x{height // upscale}", "--output", str(small)],
            check=True,
        )
    meta = json.loads((small / "transforms.json").read_text())
    factor = width / meta["w"]
    for key in ("fl_x", "fl_y", "cx", "cy"):
        meta[key] = meta[key] * factor
    meta["w"], meta["h"] = width, height
    # every view a training view (the scan reads the training cameras); the test views stay as well
    meta["train_filenames"] = [frame["file_path"] for frame in meta["frames"]]
    for frame in meta["frames"]:
        image = to_float32(read_image(small / frame["file_path"]))
        save_image(scene / frame["file_path"], resize(image, (height, width), order=1, anti_aliasing=False))
        depth = np.load(small / frame["depth_file_path"])
        (scene / frame["depth_file_path"]).parent.mkdir(parents=True, exist_ok=True)
        np.save(
            scene / frame["depth_file_path"], resize(depth, (height, width), order=0, anti_aliasing=False)
        )
    shutil.copy(small / meta["ply_file_path"], scene / meta["ply_file_path"])
    (scene / "transforms.json").write_text(json.dumps(meta, indent=1))
    print(f"scene: {len(meta['frames'])} views at {width}x{height} in {scene}")


def back_projected_model(scene: Path, source_views: int, gaussians: int, seed: int) -> GaussianCloud:
    """``gaussians`` pixels of ``source_views`` evenly spaced views as Gaussians in the dataset's frame
    (transforms.json: OpenGL camera-to-world, depth maps as z-depth along the camera's -Z)."""
    meta = json.loads((scene / "transforms.json").read_text())
    fx, fy, cx, cy = (float(meta[k]) for k in ("fl_x", "fl_y", "cx", "cy"))
    frames = meta["frames"]
    points, colours, sizes = [], [], []
    for i in np.linspace(0, len(frames) - 1, source_views).round().astype(int):
        frame = frames[i]
        depth = np.load(scene / frame["depth_file_path"])
        rgb = to_float32(read_image(scene / frame["file_path"]))[..., :3]
        v, u = np.nonzero(depth > 0)
        z = depth[v, u].astype(np.float64)
        cam = np.stack([(u + 0.5 - cx) / fx * z, -(v + 0.5 - cy) / fy * z, -z], axis=-1)
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
        points.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
        colours.append(rgb[v, u])
        sizes.append(FOOTPRINTS * z / fx)
    all_points = np.concatenate(points)
    rows = np.random.default_rng(seed).choice(
        len(all_points), size=min(gaussians, len(all_points)), replace=False
    )
    n = len(rows)
    quats = np.zeros((n, 4), np.float32)
    quats[:, 0] = 1.0
    return GaussianCloud(
        means=all_points[rows].astype(np.float32),
        log_scales=np.repeat(np.log(np.concatenate(sizes)[rows])[:, None], 3, axis=1).astype(np.float32),
        quats=quats,
        opacity_logits=np.full(n, np.log(OPACITY / (1 - OPACITY)), np.float32),
        sh_dc=dc_of_colour(np.concatenate(colours)[rows]).astype(np.float32),
        sh_rest=np.zeros((n, REST_COUNTS[3] // 3, 3), np.float32),
    )


def timed_scan(model: Path, scene: Path, out: Path) -> None:
    cmd = ["/usr/bin/time", "-v", _tool("stealth-ns"), "scan", "--model", str(model), "--data", str(scene)]
    done = subprocess.run([*cmd, "--output", str(out)], capture_output=True, text=True)
    print(done.stdout)
    if done.returncode != 0:
        sys.exit(f"scan failed:\n{done.stderr[-3000:]}")
    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", done.stderr)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    report = json.loads((out / "scan.json").read_text())
    print("scan.json seconds:", json.dumps(report.get("seconds", {})))
    print(f"wall {wall.group(1) if wall else '?'}  peak RSS {int(rss.group(1)) / 1e6:.2f} GB" if rss else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, required=True)
    parser.add_argument("--resolution", default="1152x864")
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--upscale", type=int, default=4)
    parser.add_argument("--source-views", type=int, default=12)
    parser.add_argument("--gaussians", type=int, default=999_996)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--prepare-only", action="store_true", help="make the scene and the model, scan nothing"
    )
    args = parser.parse_args()
    scene, model = args.output / "scene", args.output / "model.ply"
    make_scene(scene, args.resolution, args.views, args.upscale)
    if not model.is_file():
        cloud = back_projected_model(scene, args.source_views, args.gaussians, args.seed)
        write_gaussian_ply(model, cloud, comment="scripts/scan_at_scale.py")
        print(f"model: {len(cloud)} Gaussians, {model.stat().st_size / 1e6:.0f} MB")
    if not args.prepare_only:
        timed_scan(model, scene, args.output / "scan")


if __name__ == "__main__":
    main()
