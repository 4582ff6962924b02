"""The two formats a generated scene is written in: nerfstudio-data (images, depths, ``transforms.json``,
seed points) and Blender (NeRF-synthetic: RGBA PNGs, ``transforms_{train,val,test}.json``); the files
each writes (the manifest) and the nerfstudio-data train / test split."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from stealth_ns.images.io import save_png
from stealth_ns.scene_generator.presets import BLENDER_PRESETS, ScenePlan
from stealth_ns.scene_generator.render import Intrinsics, render_view
from stealth_ns.scene_generator.seed_points import (
    OUTLIER_FRACTION,
    SEED_POINTS,
    add_outliers,
    sample_seed_points,
)
from stealth_ns.scene_generator.writer import (
    blender_depth_path,
    blender_frame_path,
    blender_transforms_dict,
    depth_path,
    image_path,
    transforms_dict,
    write_json,
    write_ply,
)


def split_indices(views: int) -> tuple[list[int], list[int]]:
    """Train and test view indices: every 8th view (index % 8 == 0) is a test view."""
    test = [i for i in range(views) if i % 8 == 0]
    train = [i for i in range(views) if i % 8 != 0]
    return train, test


def planned_files(preset: str, plan: ScenePlan) -> list[str]:
    """Relative paths of every file :func:`make_scene` writes for ``plan`` (its manifest)."""
    if preset in BLENDER_PRESETS:
        files = ["scene.json"]
        for split, (start, stop) in plan.splits.items():
            files.append(f"transforms_{split}.json")
            for k in range(stop - start):
                files += [blender_frame_path(split, k)[2:] + ".png", blender_depth_path(split, k)]
        return files
    views = range(len(plan.c2w))
    return [
        "transforms.json",
        "sparse_pc.ply",
        "scene.json",
        *(image_path(i) for i in views),
        *(depth_path(i) for i in views),
    ]


def write_nerfstudio(output: Path, plan: ScenePlan, intr: Intrinsics, common: dict, seed: int) -> dict:
    """Render and write ``plan`` in nerfstudio-data format; returns SceneSummary's counts."""
    views = len(plan.c2w)
    train, test = split_indices(views)
    train_set = set(train)
    (output / "images").mkdir()
    (output / "depths").mkdir()
    rng = np.random.default_rng([seed, 303])
    per_view = math.ceil(SEED_POINTS / len(train))
    pts, cols, origins = [], [], []
    for i, c2w in enumerate(plan.c2w):
        view = render_view(plan, intr, c2w)
        save_png(output / image_path(i), view.image)
        np.save(output / depth_path(i), view.depth)
        if i in train_set:
            xyz, rgb = sample_seed_points(rng, view, per_view)
            pts.append(xyz)
            cols.append(rgb)
            origins.append(np.broadcast_to(c2w[:3, 3], xyz.shape))
    xyz, rgb = np.concatenate(pts), np.concatenate(cols)
    fraction = OUTLIER_FRACTION.get(plan.preset, 0.0)
    n_outliers = 0
    if fraction > 0:
        xyz, n_outliers = add_outliers(
            np.random.default_rng([seed, 606]), xyz, np.concatenate(origins), fraction
        )
    c2w_out = plan.exported_c2w()
    write_ply(output / "sparse_pc.ply", xyz, rgb)
    write_json(output / "transforms.json", transforms_dict(intr, c2w_out, train, test))
    info = {
        **common,
        "format": "nerfstudio-data",
        "n_train": len(train),
        "n_test": len(test),
        "depth": "z-depth along camera -Z, world units, float32 .npy, 0 = sky (no surface)",
        "n_points": int(xyz.shape[0]),
    }
    if fraction > 0:
        info["n_outliers"] = n_outliers
    write_json(output / "scene.json", info)  # last: its presence means the scene is complete
    return {"n_train": len(train), "n_test": len(test), "n_points": int(xyz.shape[0])}


def write_blender(output: Path, plan: ScenePlan, intr: Intrinsics, common: dict) -> dict:
    """Render and write ``plan`` in the Blender (NeRF-synthetic) format; returns SceneSummary's counts."""
    c2w_out = plan.exported_c2w()
    camera_angle_x = float(np.deg2rad(plan.hfov_deg))
    scale = np.float32(plan.export_scale)  # depth in export-frame units
    counts = {}
    for split, (start, stop) in plan.splits.items():
        (output / split).mkdir()
        (output / "depths" / split).mkdir(parents=True)
        for k, i in enumerate(range(start, stop)):
            view = render_view(plan, intr, plan.c2w[i])
            save_png(output / split / f"r_{k}.png", view.rgba())
            np.save(output / blender_depth_path(split, k), (view.depth * scale).astype(np.float32))
        write_json(
            output / f"transforms_{split}.json",
            blender_transforms_dict(camera_angle_x, c2w_out[start:stop], split),
        )
        counts[split] = stop - start
    write_json(
        output / "scene.json",
        {
            **common,
            "format": "blender",
            "n_train": counts["train"],
            "n_val": counts["val"],
            "n_test": counts["test"],
            "splits": {k: list(v) for k, v in plan.splits.items()},
            "depth": "z-depth along camera -Z, world units, float32 .npy, 0 = background (no surface)",
            "n_points": 0,
        },
    )
    return {
        "n_train": counts["train"],
        "n_test": counts["test"],
        "n_points": 0,
        "dataparser": "blender-data",
        "n_val": counts["val"],
    }
