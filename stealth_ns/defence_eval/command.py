"""``stealth-ns defend``: can the poison be found, and what does removing it cost?

For an attacked run (and optionally the clean run of the same scene) every post-hoc defence of
:mod:`stealth_ns.defences.posthoc` scores each Gaussian; against the ground-truth poison tag that
gives ROC-AUC and average precision (:mod:`stealth_ns.defences.detection`). Each defence then prunes
at its own rule (the operating point) and at a sweep of pruned fractions; for every cut the model is
rendered again without the pruned Gaussians: **V-illusory after** (masked PSNR of the poisoned
views against the illusion target) and **V-test cost** (held-out PSNR lost, in dB, against the
undefended model). The training-time defence ``input-filter`` retrains the run on filtered images
(:mod:`stealth_ns.images.input_filter`) and is scored on the retrained model.

Outputs in ``--output``: ``defend.json`` (every number), ``defend.md`` (the table), ``roc.png``,
``curves.png`` (V-illusory vs V-test cost over the sweep), ``poisoned_view.png`` (the poisoned view
before and after each defence), ``pruned/DEFENCE/...`` (each defended model as a nerfstudio run)
and ``input-filter/`` (the retrained run). ``stealth-ns report --defend DIR`` adds the table and the
figures to ``report.html``. docs/design/defences.md.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from stealth_ns.defence_eval.arguments import check_arguments
from stealth_ns.defence_eval.evaluate import (
    Evaluator,
    Target,
    cut_metrics,
    defender_images,
    load_target,
)
from stealth_ns.defence_eval.outputs import FIGURES, TABLE_FILE, fmt, pct, write_outputs
from stealth_ns.defence_eval.result_file import DEFEND_FILE
from stealth_ns.defence_eval.rule import DEFEAT_RULE
from stealth_ns.defences import detection
from stealth_ns.defences.config import POSTHOC, DefendConfig
from stealth_ns.defences.posthoc import DESCRIPTIONS, DefenceInputs, Scored, score
from stealth_ns.defences.signals import poison_tags
from stealth_ns.foundation.errors import StealthNSError, write_error
from stealth_ns.foundation.json_io import json_safe, write_json_atomic
from stealth_ns.foundation.provenance import software_and_hardware
from stealth_ns.runs.loaded import load_run
from stealth_ns.runs.pair import RunPair


def defence_entry(
    scored: Scored, evaluate: Evaluator, baseline: dict, is_poison: np.ndarray
) -> dict[str, Any]:
    """defend.json's entry of one post-hoc defence: detection, operating point, sweep."""
    curve = []
    for fraction in detection.sweep_fractions():
        mask = detection.prune_mask_top_fraction(scored.scores, fraction)
        curve.append({"fraction": fraction, **cut_metrics(evaluate, baseline, mask, is_poison)})
    return {
        "kind": "post-hoc",
        "description": DESCRIPTIONS[scored.name],
        "rule": scored.rule,
        **detection.detection_metrics(scored.scores, is_poison),
        "operating_point": cut_metrics(evaluate, baseline, scored.pruned, is_poison),
        "curve": curve,
        "score_seconds": scored.seconds,
    }


def score_posthoc(
    target: Target, cfg: DefendConfig, echo: Callable[[str], None] | None = None
) -> tuple[dict[str, Any], dict[str, Scored], dict[str, Any]]:
    """Every post-hoc defence of ``cfg`` on ``target``, nothing written: ``(baseline, scored, entries)``
    (the undefended model's numbers, each defence's scores and mask, its defend.json entry).
    ``echo``: where the progress lines go (None: nowhere)."""
    say = echo or (lambda line: None)
    model = target.model
    is_poison = poison_tags(model)
    evaluate = Evaluator(target)
    baseline = evaluate(None)
    inputs = DefenceInputs(
        model,
        target.run.pipeline.datamanager.train_dataset.cameras,
        defender_images(target),
        target.learning_rates,
    )
    scored, entries = {}, {}
    for name in [d for d in cfg.defences if d in POSTHOC]:
        say(f"defend: {name} ...")
        scored[name] = score(name, inputs, cfg)
        entries[name] = defence_entry(scored[name], evaluate, baseline, is_poison)
        say(entry_line(name, entries[name]))
    return baseline, scored, entries


def write_pruned_runs(
    target: Target, scored: dict[str, Scored], entries: dict[str, Any], output: Path
) -> None:
    """Each post-hoc defence's model written as a run under ``output/pruned`` (its ``pruned_run``)."""
    from stealth_ns.defences.pruned_run import write_pruned_run

    for name, entry in entries.items():
        info = {"defence": name, "rule": scored[name].rule}
        keep = torch.from_numpy(~scored[name].pruned)
        config = write_pruned_run(
            target.run.config_path, target.checkpoint, keep, output / "pruned", name, info, within=output
        )
        entry["pruned_run"] = str(config)


def entry_line(name: str, entry: dict[str, Any]) -> str:
    """One defence's result as a line: AUROC, AP, what its rule removes, V-illusory after, V-test cost."""
    op = entry.get("operating_point") or {}
    return (
        f"defend: {name}: AUROC {fmt(entry.get('auroc'), 3)}, AP {fmt(entry.get('average_precision'), 3)}, "
        f"poison removed {pct(op.get('poison_removed'))}, clean removed {pct(op.get('clean_removed'))}, "
        f"V-illusory after {fmt(op.get('v_illusory_psnr'))} dB, "
        f"V-test cost {fmt(op.get('v_test_cost'))} dB"
    )


def run_defend(
    run: Path, output: Path, cfg: DefendConfig | None = None, clean: Path | None = None
) -> dict[str, Any]:
    """``stealth-ns defend``: every defence of ``cfg`` on the attacked run ``run``; writes ``output``.

    Nothing is written before the defences are scored (and ``clean`` checked); then an earlier result's
    defend.json, defend.md and figures are removed (they would describe pruned runs replaced now) and
    defend.json is written last: a write that fails (a full disk) leaves no defend.json, and is one
    line naming the file and the reason."""
    from stealth_ns.defence_eval.input_filter_retrain import run_input_filter

    cfg = cfg or DefendConfig()
    output = Path(output)
    check_arguments(Path(run), output, cfg, None if clean is None else Path(clean))
    t0 = time.perf_counter()
    target = load_target(Path(run))
    baseline, scored, entries = score_posthoc(target, cfg, echo=lambda line: print(line, flush=True))
    result: dict[str, Any] = {
        "generator": "stealth-ns defend",
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "run": str(target.run.config_path.resolve()),
        "settings": cfg.__dict__,
        "defeat_rule": DEFEAT_RULE,
        "n_gaussians": int(target.model.num_points),
        "n_poison": int(poison_tags(target.model).sum()),
        "poisoned_views": [v.name for v in target.record.views],
        "undefended": baseline,
        "defences": entries,
    }
    if clean is not None:
        result["clean"] = clean_reference(target, Path(clean))
    remove_result_files(output)
    try:
        write_pruned_runs(target, scored, entries, output)
        if "input-filter" in cfg.defences:
            result["defences"]["input-filter"] = run_input_filter(target, cfg, output, baseline)
            print(entry_line("input-filter", result["defences"]["input-filter"]), flush=True)
        result["environment"] = software_and_hardware()
        result["seconds"] = round(time.perf_counter() - t0, 1)
        result = json_safe(result)
        write_outputs(output, result, target, scored)
        write_json_atomic(output / DEFEND_FILE, result)
    except OSError as err:
        raise write_error(err.filename or output, err) from None
    return result


def remove_result_files(output: Path) -> None:
    """Delete defend.json, defend.md and the figures an earlier ``stealth-ns defend`` wrote into
    ``output`` (a one-line StealthNSError when one cannot be removed); any other file is left alone."""
    for name in (DEFEND_FILE, TABLE_FILE, *FIGURES.values()):
        path = output / name
        if path.is_file() and not path.is_symlink():
            try:
                path.unlink()
            except OSError as err:
                raise StealthNSError(
                    f"cannot replace {path} of an earlier result: {err.strerror or err}"
                ) from None


def clean_reference(target: Target, clean: Path) -> dict[str, Any]:
    """The clean run's V-test PSNR and V-illusory (what a perfect defence could reach), same renders."""
    clean_run = load_run(clean)
    if clean_run.attack_enabled:
        raise StealthNSError(
            f"--clean {clean} was trained with the attack on; train the clean run with "
            "--pipeline.attack.enabled False (or any other splatting method)"
        )
    pair = RunPair(target.run, clean_run, target.record)
    pair.check_same_dataset()
    evaluate = Evaluator(target, clean_run)
    return {
        "run": str(clean_run.config_path.resolve()),
        "n_gaussians": int(clean_run.model.num_points),
        **evaluate(None),
    }
