"""The input-filter defence of ``stealth-ns defend``: retrain the attacked run on filtered images.

The retrained run is the attacked run's own config (same method, scene, attack, seed, iterations)
with ``pipeline.datamanager.input_filter`` set, trained by ``ns-train METHOD --load-config`` into
``OUTPUT/input-filter/``. A finished retrain with the same filter of the same run is reused
(``retrain.json``); anything else there is replaced.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from stealth_ns.defences.config import DefendConfig
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.foundation.output_folder import remove_tree
from stealth_ns.method.safe_config import load_config
from stealth_ns.runs.training import bin_path, configured_iterations, run_command

if TYPE_CHECKING:
    from stealth_ns.defence_eval.evaluate import Target

RETRAIN_MARKER = "retrain.json"


def filtered_config(config_path: Path, root: Path, kind: str, sigma: float) -> tuple[Any, Path]:
    """The run's config with the input filter on and its outputs under ``root``; returns it and its
    run folder (``root/input-filter/METHOD/TIMESTAMP``)."""
    config = load_config(config_path)
    dm = config.pipeline.datamanager
    if not hasattr(dm, "input_filter"):
        raise StealthNSError(f"{config_path}'s datamanager has no input filter (not a stealth-splat run)")
    dm.input_filter, dm.input_filter_sigma = kind, float(sigma)
    if dm.dataparser.data is not None:
        dm.dataparser.data = Path(dm.dataparser.data).resolve()
    config.output_dir = Path(root).resolve()
    config.experiment_name = "input-filter"
    config.load_dir, config.load_checkpoint = None, None
    config.vis = "tensorboard"
    return config, config.get_base_dir()


def _identity(target: Target, cfg: DefendConfig) -> dict[str, Any]:
    return {
        "source_run": str(target.run.config_path.resolve()),
        "source_checkpoint_bytes": target.checkpoint.stat().st_size,
        "source_checkpoint_mtime": target.checkpoint.stat().st_mtime,
        "filter": cfg.input_filter,
        "sigma": cfg.input_filter_sigma if cfg.input_filter == "gaussian" else None,
    }


def retrain(target: Target, cfg: DefendConfig, output: Path) -> tuple[Path, bool]:
    """Train (or reuse) the filtered run; returns its ``config.yml`` and whether it was reused."""
    config, run_dir = filtered_config(
        target.run.config_path, output, cfg.input_filter, cfg.input_filter_sigma
    )
    identity = _identity(target, cfg)
    marker = run_dir / RETRAIN_MARKER
    try:
        if json.loads(marker.read_text()) == identity:
            return run_dir / "config.yml", True
    except (OSError, ValueError):
        pass
    remove_tree(run_dir, output)  # an earlier, unfinished retraining (never through a link out)
    run_dir.mkdir(parents=True)
    spec = run_dir.parent / f"{run_dir.name}.input-config.yml"
    spec.write_text(yaml.dump(config), encoding="utf-8")
    log = run_dir.parent / f"{run_dir.name}.ns-train.log"
    print(f"defend: input-filter: retraining on {cfg.input_filter}-filtered images (log: {log})", flush=True)
    run_command([bin_path("ns-train"), config.method_name, "--load-config", str(spec)], log, stream=False)
    final = (
        run_dir / "nerfstudio_models" / f"step-{configured_iterations(run_dir / 'config.yml') - 1:09d}.ckpt"
    )
    if not final.is_file():
        raise StealthNSError(f"the input-filter retrain ended without {final}; see {log}")
    write_json_atomic(marker, identity)
    return run_dir / "config.yml", False


def run_input_filter(target: Target, cfg: DefendConfig, output: Path, baseline: dict) -> dict[str, Any]:
    """defend.json's ``input-filter`` entry: the retrained model's V-illusory and V-test cost."""
    from stealth_ns.defence_eval.evaluate import Evaluator, cut_metrics
    from stealth_ns.runs.loaded import load_run

    t0 = time.perf_counter()
    config_path, reused = retrain(target, cfg, output)
    run = load_run(config_path)
    tags = run.model.poison_mask.cpu().numpy()
    after = cut_metrics(Evaluator(target, run), baseline, np.zeros(tags.shape[0], dtype=bool), tags)
    for key in ("n_pruned", "n_poison_pruned", "n_clean_pruned", "poison_removed", "clean_removed"):
        after.pop(key, None)
    return {
        "kind": "training-time",
        "description": f"retrained on {cfg.input_filter}-filtered training images",
        "rule": cfg.input_filter
        + (f", sigma {cfg.input_filter_sigma:g} px" if cfg.input_filter == "gaussian" else ""),
        "auroc": None,
        "average_precision": None,
        "reason": "not a detector: it scores no Gaussian, it changes what the model is trained on",
        "operating_point": {**after, "n_gaussians": int(tags.shape[0]), "n_poison_after": int(tags.sum())},
        "curve": [],
        "retrained_run": str(config_path),
        "reused": reused,
        "seconds": round(time.perf_counter() - t0, 1),
    }
