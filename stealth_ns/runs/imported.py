"""A model from any trainer as a :class:`~stealth_ns.runs.loaded.LoadedRun`: a 3DGS PLY or a stock
splatfacto run, loaded into a stealth-ns model on the dataset's cameras so that every tool that reads
runs (scan, report) renders and scores it as it does our own.

* **PLY** (the official 3DGS code, gsplat, OpenSplat, ``ns-export gaussian-splat``): read by
  :mod:`stealth_ns.gaussians.ply` (a few broken rows left out, said in one printed line:
  :mod:`stealth_ns.gaussians.broken_rows`), moved into nerfstudio's frame from the frame it was trained in
  (:mod:`stealth_ns.datasets.frames`; ``auto`` tries each and keeps the one whose renders match the
  training images best), loaded into a ``stealth-splat-lite`` pipeline set up on ``--data``.
* **nerfstudio run** (``config.yml``): a stealth-ns run loads as it is (:func:`load_run`); another
  splatfacto-family run (stock ``splatfacto``, ``splatfacto-big``...) is read from its checkpoint's
  Gaussians into a stealth-ns model on the same dataset (its cameras are in nerfstudio's frame).

The loaded model renders on the CPU backend, or gsplat on CUDA, as our runs do.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from stealth_ns.attack.config import AttackConfig
from stealth_ns.datasets.frames import FRAMES, frame_transforms
from stealth_ns.datasets.source import SceneSource, inspect_folder
from stealth_ns.defences.signals import frustum_depth_ratios
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.model_files import is_model_file, model_format, read_model_file
from stealth_ns.gaussians.ply import GaussianCloud
from stealth_ns.gaussians.transform import transform_cloud
from stealth_ns.images.io import rgb_float
from stealth_ns.images.metrics import psnr
from stealth_ns.method.camera_geometry import camera_matrices
from stealth_ns.method.checkpoints import find_checkpoint, read_checkpoint
from stealth_ns.method.model import StealthSplatModel
from stealth_ns.method.model_cloud import LOADED_STEP, cloud_of_model, cloud_of_params, load_cloud
from stealth_ns.method.render_view import render_camera
from stealth_ns.poisoned_datasets.dataset_copy import SourceDataset
from stealth_ns.runs.loaded import LoadedRun, load_run
from stealth_ns.runs.official_output import MIN_IN_VIEW, is_official_output, load_official_output
from stealth_ns.runs.paths import run_file

#: The method whose model and pipeline hold an imported model (its renderer, its fine-tune rates).
HOST_METHOD = "stealth-splat-lite"
#: Training views rendered to tell the frames apart (evenly spaced).
FRAME_TEST_VIEWS = 3


@dataclass
class ImportedModel:
    """A model under scan or report, from wherever it came."""

    run: LoadedRun
    kind: str
    """"ply", "stealth-ns run" or "splatfacto run" (with the method's name)."""
    cloud: GaussianCloud
    """The Gaussians as read, in the model's own frame (the scan's cleaned PLY is written from them);
    a model file's without the broken rows its reader left out (``cloud.left_out``)."""
    frame: str = "nerfstudio"
    frame_match: dict[str, dict[str, float]] = field(default_factory=dict)
    """Each frame tried -> ``psnr`` (dB, mean over the test views), ``in_view`` (share of Gaussians
    inside some training view) and ``flat_psnr`` (:func:`frame_match`); empty when the frame was known."""


def load_model(model: Path, data: Path | None = None, frame: str = "auto") -> ImportedModel:
    """Load ``model`` (a PLY, a run's config.yml or run folder) on ``data`` (required for a PLY; a run's
    own dataset by default). The broken rows left out of a model file are printed in one line (scan,
    report). StealthNSError with one line for every problem."""
    model = Path(model)
    if frame not in ("auto", *FRAMES):
        raise StealthNSError(f"--frame must be auto or one of {', '.join(FRAMES)}, got {frame!r}")
    if is_official_output(model):  # an official 3DGS output folder: stealth_ns.runs.official_output
        return load_official_output(model, data, frame, load_model)
    if is_model_file(model):
        if data is None:
            raise StealthNSError(
                f"--data is needed with a PLY, .splat or .spz model ({model}): the dataset whose cameras "
                "it was trained on"
            )
        return _load_ply(model, data, frame)
    config_path = run_file(model)
    if not config_path.is_file():
        raise StealthNSError(
            f"{model} is neither a PLY file nor a run (no config.yml; a model file is .ply, .splat or .spz)"
        )
    from stealth_ns.method.safe_config import load_config

    config = load_config(config_path)
    if frame not in ("auto", "nerfstudio"):
        raise StealthNSError(f"--frame {frame}: a nerfstudio run is in nerfstudio's frame (give auto)")
    if "StealthSplat" in type(config.pipeline.model).__name__:
        run = load_run(config_path)
        _check_same_data(run, data)
        return ImportedModel(run, "stealth-ns run", cloud_of_model(run.model))
    return _load_splatfacto_run(config_path, config, data)


def _check_same_data(run: LoadedRun, data: Path | None) -> None:
    if data is not None and Path(data).resolve() != run.data.resolve():
        raise StealthNSError(
            f"--data {data}: the run {run.config_path} was trained on {run.data} (leave --data out)"
        )


def host_config(scene: SceneSource, sh_degree: int = 3) -> Any:
    """The ``TrainerConfig`` of :data:`HOST_METHOD` on ``scene`` (attack off), as ns-train would make it,
    with SH up to ``sh_degree`` (at least 3, splatfacto's)."""
    from stealth_ns.poisoned_datasets.setup import trainer_config

    config = trainer_config(SourceDataset(scene), AttackConfig(enabled=False), HOST_METHOD)
    config.pipeline.model.sh_degree = max(3, sh_degree)
    return config


def host_run(config: Any, label: Path, checkpoint: Path | None = None) -> LoadedRun:
    """Set up ``config``'s pipeline for evaluation (held-out split loaded, training images cached) as
    a :class:`LoadedRun` named ``label`` (``checkpoint``: the one its Gaussians come from, if any); its
    model's rows are to be replaced."""
    from stealth_ns.poisoned_datasets.setup import setup_pipeline

    pipeline = setup_pipeline(config, test_mode="test")
    pipeline.eval()
    pipeline.datamanager.cached_train  # noqa: B018 - caches (and undistorts) the training images
    return LoadedRun(Path(label), pipeline, LOADED_STEP, config, checkpoint)


def _load_ply(path: Path, data: Path, frame: str) -> ImportedModel:
    cloud = read_model_file(path)
    if cloud.left_out is not None:
        print(f"{path}: {cloud.left_out.line()}")
    scene = inspect_folder("--data", str(data))
    run = host_run(host_config(scene), path)
    transforms = frame_transforms(run.pipeline.datamanager.train_dataparser_outputs, scene)
    if frame != "auto" and frame not in transforms:
        raise StealthNSError(f"--frame {frame}: {data} has no such frame (it has {', '.join(transforms)})")
    candidates: dict[str, np.ndarray] = {}
    for name, matrix in (transforms if frame == "auto" else {frame: transforms[frame]}).items():
        # frames that coincide (a Blender dataset's own frame is nerfstudio's) are tried once
        if not any(np.allclose(matrix, tried) for tried in candidates.values()):
            candidates[name] = matrix
    match: dict[str, dict[str, float]] = {}
    for name, matrix in candidates.items():
        load_cloud(run.model, transform_cloud(cloud, matrix))
        match[name] = frame_match(run)
    usable = {k: v for k, v in match.items() if v["in_view"] >= MIN_IN_VIEW}
    if not usable:
        raise StealthNSError(
            f"{path} does not match the cameras of {data}: in no frame tried do at least "
            f"{MIN_IN_VIEW:.0%} of its Gaussians sit inside a training view: {describe_matches(match)}; "
            f"a flat image of each photo's mean colour scores {next(iter(match.values()))['flat_psnr']:.1f} "
            "dB (the render-match floor at --render-match-floor 0): the model was trained on another "
            "dataset, or in a frame stealth-ns does not know (docs/design/scan.md)"
        )
    chosen = max(usable, key=lambda k: usable[k]["psnr"])
    if chosen != list(candidates)[-1]:
        load_cloud(run.model, transform_cloud(cloud, candidates[chosen]))
    return ImportedModel(run, model_format(path), cloud, chosen, match if frame == "auto" else {})


def describe_matches(match: dict[str, dict[str, float]]) -> str:
    """Each frame of ``match`` (:func:`frame_match`'s, by frame) with its render match and share of
    Gaussians in view, in one line: ``nerfstudio (render match 13.4 dB, 81% of the Gaussians in view),
    ...``."""
    return ", ".join(
        f"{name} (render match {m['psnr']:.1f} dB, {m['in_view']:.0%} of the Gaussians in view)"
        for name, m in match.items()
    )


@torch.no_grad()
def frame_match(run: LoadedRun) -> dict[str, float]:
    """How well the loaded model fits the run's training cameras: ``in_view``, the share of its centres
    in front of some camera inside its image; ``psnr``, the mean PSNR (dB) of
    :data:`FRAME_TEST_VIEWS` training views' renders against their images; ``flat_psnr``, the same for
    a flat image of each one's mean colour (what a render that shows nothing of the scene reaches:
    the scan's yardstick, :mod:`stealth_ns.scan.fit`)."""
    model: StealthSplatModel = run.model
    dm = run.pipeline.datamanager
    cameras = dm.train_dataset.cameras
    viewmats, ks, sizes = camera_matrices(cameras)
    ratios = frustum_depth_ratios(
        model.means.detach().double().cpu().numpy(), viewmats, ks, sizes, np.ones(len(cameras))
    )
    views = np.unique(np.linspace(0, len(cameras) - 1, FRAME_TEST_VIEWS).round().astype(int))
    scores, flat = [], []
    for v in views:
        out = render_camera(model, cameras[int(v) : int(v) + 1])
        gt = model.composite_with_background(model.get_gt_img(dm.cached_train[v]["image"]), out["background"])
        gt = rgb_float(gt.cpu())
        scores.append(min(psnr(out["rgb"].float().cpu(), gt), 99.0))
        flat.append(min(psnr(gt.mean(dim=(0, 1), keepdim=True).expand_as(gt), gt), 99.0))
    return {
        "psnr": round(float(np.mean(scores)), 2),
        "in_view": round(float(np.isfinite(ratios).mean()), 4),
        "flat_psnr": round(float(np.mean(flat)), 2),
    }


def _load_splatfacto_run(config_path: Path, config: Any, data: Path | None) -> ImportedModel:
    """A splatfacto-family run not trained by stealth-ns: its checkpoint's Gaussians in our model."""
    model_cfg = config.pipeline.model
    if not hasattr(model_cfg, "sh_degree") or "splatfacto" not in str(config.method_name):
        raise StealthNSError(
            f"{config_path} was trained with {config.method_name!r}, not a Gaussian-splatting method "
            "(export a PLY of its Gaussians, or give a splatfacto or stealth-splat run)"
        )
    checkpoint = find_checkpoint(config_path.parent / "nerfstudio_models", flag="checkpoint folder")
    state = read_checkpoint(checkpoint)["pipeline"]
    prefix = next((p for p in ("_model.gauss_params.", "model.gauss_params.") if f"{p}means" in state), None)
    if prefix is None:
        raise StealthNSError(f"{checkpoint} holds no Gaussians (no gauss_params.means)")
    params = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
    cloud = cloud_of_params(params, int(model_cfg.sh_degree))
    dm = config.pipeline.datamanager
    dataset = Path(data) if data is not None else Path(dm.data or dm.dataparser.data or "")
    host = host_config(inspect_folder("--data", str(dataset)), cloud.sh_degree)
    host.pipeline.datamanager.dataparser = copy.deepcopy(dm.dataparser)
    host.pipeline.datamanager.dataparser.data = dataset
    host.pipeline.model.background_color = model_cfg.background_color
    run = host_run(host, config_path, checkpoint)
    load_cloud(run.model, cloud)
    return ImportedModel(run, f"splatfacto run ({config.method_name})", cloud)
