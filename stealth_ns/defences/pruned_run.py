"""A defended model as a nerfstudio run: ``ns-eval``, ``ns-viewer`` and ``ns-export`` load it.

The run is the attacked run with the pruned Gaussians removed from its final checkpoint. Layout,
nerfstudio's: ``ROOT/DEFENCE/METHOD/TIMESTAMP/`` with ``config.yml`` (its output paths pointing
there, the dataset path made absolute), ``nerfstudio_models/step-N.ckpt`` (the pipeline's state
only: it can be evaluated and viewed, not resumed), the attack record (``attack/``) and dataset
fingerprint copied, and ``defence.json`` saying what was pruned. ``ns-export gaussian-splat`` of it
writes a PLY with the poison tag (:mod:`stealth_ns.method.export`).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import torch
import yaml

from stealth_ns.foundation.fingerprint import FINGERPRINT_FILE
from stealth_ns.foundation.json_io import write_json_atomic, write_text_atomic
from stealth_ns.foundation.output_folder import remove_tree
from stealth_ns.gaussians.rows import select_rows
from stealth_ns.method.checkpoints import read_checkpoint, save_checkpoint
from stealth_ns.method.safe_config import load_config

GAUSS_PREFIX = "_model.gauss_params."
STRATEGY_STATE = "_model._extra_state"


def pruned_state(pipeline_state: dict[str, Any], keep: torch.Tensor) -> dict[str, Any]:
    """A pipeline state dict with only the kept Gaussians (``keep``: [N] bool): the
    ``gauss_params`` rows and gsplat's per-Gaussian statistics."""
    state = dict(pipeline_state)
    rows = select_rows({k: v for k, v in state.items() if k.startswith(GAUSS_PREFIX)}, keep)
    state.update(rows)
    if isinstance(state.get(STRATEGY_STATE), dict):
        state[STRATEGY_STATE] = select_rows(state[STRATEGY_STATE], keep)
    return state


def write_pruned_run(
    config_path: Path,
    checkpoint: Path,
    keep: torch.Tensor,
    root: Path,
    name: str,
    info: dict[str, Any],
    within: Path | None = None,
) -> Path:
    """Write the run ``config_path`` (final checkpoint ``checkpoint``) pruned to ``keep`` under ``root``
    as the experiment ``name``; returns its ``config.yml``. ``info`` goes into ``defence.json``. An
    earlier one is replaced, unless a symbolic link between ``within`` (the command's ``--output``;
    default ``root``) and it leads elsewhere (:func:`~stealth_ns.foundation.output_folder.remove_tree`)."""
    config = load_config(config_path)
    run_dir = Path(config_path).parent
    data = config.pipeline.datamanager.dataparser.data
    if data is not None:
        config.pipeline.datamanager.dataparser.data = Path(data).resolve()
    config.output_dir = Path(root).resolve()
    config.experiment_name = name
    config.load_dir, config.load_checkpoint = None, None
    base = config.get_base_dir()
    # an earlier one of the command's, never through a link out of its --output (``base`` is resolved)
    remove_tree(Path(root) / base.relative_to(config.output_dir), root if within is None else within)
    (base / config.relative_model_dir).mkdir(parents=True)
    loaded = read_checkpoint(checkpoint)
    state = pruned_state(loaded["pipeline"], keep.cpu())
    save_checkpoint(
        base / config.relative_model_dir / checkpoint.name, {"step": loaded["step"], "pipeline": state}
    )
    write_text_atomic(base / "config.yml", yaml.dump(config))
    if (run_dir / "attack").is_dir():
        shutil.copytree(run_dir / "attack", base / "attack")
    if (run_dir / FINGERPRINT_FILE).is_file():
        shutil.copy2(run_dir / FINGERPRINT_FILE, base / FINGERPRINT_FILE)
    n_kept = int(keep.sum())
    info = {**info, "source_run": str(config_path), "n_kept": n_kept, "n_pruned": int(keep.numel()) - n_kept}
    write_json_atomic(base / "defence.json", info)
    return base / "config.yml"
