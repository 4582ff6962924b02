"""An official 3DGS output folder (:mod:`stealth_ns.datasets.official_output`) loaded as a PLY on the
cameras it was trained on, in the frame it was trained in: no frame search.

* **With photos** (``--data``, or cfg_args' ``source_path`` when it is a dataset here):
  :func:`load_official_output`, the newest PLY loaded on that dataset as any PLY is, in the official
  frame (:func:`~stealth_ns.datasets.official_output.official_frame`) unless ``--frame`` names another.
* **Without photos**: :func:`load_on_cameras`, the newest PLY loaded on a nerfstudio-data dataset of
  cameras.json's cameras with flat placeholder images (written into a folder the caller owns and
  removes); only what needs no photos may be read from it (``stealth-ns scan`` skips the rest).

Both load through ``load_model`` (:func:`stealth_ns.runs.imported.load_model`, passed in: that module
dispatches official folders here) and return its ``ImportedModel``, ``kind`` naming the output.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.datasets.official_output import (
    CAMERAS_FILE,
    OfficialOutput,
    TrainingSplit,
    is_official_output,
    official_frame,
    photo_source,
    read_official_output,
    training_size,
    write_camera_dataset,
)
from stealth_ns.datasets.source import inspect_folder
from stealth_ns.defences.signals import frustum_depth_ratios
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.ply import read_gaussian_ply

__all__ = ["is_official_output", "load_official_output", "load_on_cameras", "official_kind"]

LoadModel = Callable[[Path, Path, str], Any]
"""``load_model(ply, dataset, frame) -> ImportedModel``."""
#: Least share of the Gaussians that must sit in front of some training camera, inside its image:
#: ``load_model`` refuses a PLY below it, and so does a scan on an official output's cameras alone.
MIN_IN_VIEW = 0.5


def official_kind(output: OfficialOutput) -> str:
    """The model's kind in scan.json."""
    return f"official 3DGS output (iteration {output.iteration})"


def load_official_output(folder: Path, data: Path | None, frame: str, load_model: LoadModel) -> Any:
    """The newest PLY of the official output ``folder`` on the dataset with its photos (``data``, else
    cfg_args' ``source_path``), in the official frame when ``frame`` is "auto"; a one-line
    StealthNSError when there are no photos (:func:`load_on_cameras` loads it without)."""
    output = read_official_output(folder)
    photos = photo_source(output, data)
    if photos.dataset is None:
        raise StealthNSError(
            f"{folder} is an official 3DGS output with {photos.note}: give --data, the dataset it was "
            "trained on"
        )
    if frame == "auto":
        frame = official_frame(inspect_folder("--data", str(photos.dataset)))
    imported = load_model(output.ply, photos.dataset, frame)
    imported.kind = official_kind(output)
    return imported


def load_on_cameras(
    output: OfficialOutput, workspace: Path, frame: str, load_model: LoadModel
) -> tuple[Any, TrainingSplit]:
    """The newest PLY of ``output`` on its cameras alone: cameras.json written into the empty folder
    ``workspace`` as a nerfstudio-data dataset with placeholder images
    (:func:`~stealth_ns.datasets.official_output.write_camera_dataset`), the model loaded on it in its
    own frame. Returns the model and which cameras are its training views."""
    if frame not in ("auto", "dataset"):
        raise StealthNSError(
            f"--frame {frame}: without photos the model is taken in the frame of its {CAMERAS_FILE} "
            "(give auto)"
        )
    split = write_camera_dataset(output, workspace)
    try:
        imported = load_model(output.ply, workspace, "dataset")
    except StealthNSError as err:  # its words, not those of a comparison with the placeholders
        share = in_view_share(read_gaussian_ply(output.ply).means, output, split.training)
        if share < MIN_IN_VIEW:
            raise StealthNSError(
                f"{output.ply} does not sit on the cameras of {output.cameras_file}: only {share:.0%} of "
                f"its Gaussians are inside a training view (at least {MIN_IN_VIEW:.0%} needed): the PLY "
                "and the cameras come from different runs or scenes"
            ) from None
        raise StealthNSError(str(err).replace(str(workspace), str(output.cameras_file))) from None
    imported.kind = official_kind(output)
    return imported, split


def in_view_share(means: np.ndarray, output: OfficialOutput, views: tuple[int, ...]) -> float:
    """The share of the centres ``means`` (``[N, 3]``, the output's frame) in front of one of the
    cameras ``views`` (indices into cameras.json) and inside its image."""
    cameras = [output.cameras[i] for i in views]
    viewmats = np.zeros((len(cameras), 4, 4))
    ks = np.zeros((len(cameras), 3, 3))
    sizes = np.zeros((len(cameras), 2))
    for v, camera in enumerate(cameras):
        viewmats[v, :3, :3] = camera.rotation.T  # world-to-camera, OpenCV axes
        viewmats[v, :3, 3] = -camera.rotation.T @ camera.position
        viewmats[v, 3, 3] = 1.0
        w, h = training_size(camera, output.options.get("resolution", -1))
        ks[v] = [
            [camera.fx * w / camera.width, 0, w / 2],
            [0, camera.fy * h / camera.height, h / 2],
            [0, 0, 1],
        ]
        sizes[v] = (w, h)
    ratios = frustum_depth_ratios(
        np.asarray(means, dtype=np.float64), viewmats, ks, sizes, np.ones(len(cameras))
    )
    return float(np.isfinite(ratios).mean())
