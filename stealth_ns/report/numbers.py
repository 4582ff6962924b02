"""The report's numbers for a pair of runs: V-illusory, V-test and its drop, the success verdicts,
the poisoned run's stealth under the post-hoc defences, and the neighbour-view curve of the paper's
Fig. 8.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stealth_ns.attack.coverage import coverage_split
from stealth_ns.attack.views import rotate_pose, scene_center, scene_up
from stealth_ns.defence_eval.stealth import measure_stealth
from stealth_ns.images.metrics import LazyLPIPS, illusion_metrics, psnr, v_illusory
from stealth_ns.report.success import attack_success, success_verdicts
from stealth_ns.runs.loaded import LoadedRun, poison_coverage, render
from stealth_ns.runs.pair import RunPair

#: Neighbour-view angles (degrees) about the scene's vertical axis, as the paper's Fig. 8.
NEIGHBOUR_ANGLES: tuple[float, ...] = tuple(float(a) for a in np.arange(-20.0, 20.01, 2.5))


def _held_out_metrics(run: LoadedRun) -> dict[str, float | None]:
    """nerfstudio's V-test metrics (held-out split) of one run, LPIPS None when unavailable."""
    from nerfstudio.pipelines.base_pipeline import VanillaPipeline

    metrics = VanillaPipeline.get_average_eval_image_metrics(run.pipeline)
    return {k: (float(metrics[k]) if k in metrics else None) for k in ("psnr", "ssim", "lpips")}


def pair_metrics(pair: RunPair, lpips: LazyLPIPS | None = None, stealth: bool = True) -> dict[str, Any]:
    """The report's numbers (see the module docstring); keys documented in docs/design/evaluation.md.
    ``stealth``: also the poisoned run's stealth under the post-hoc defences
    (:func:`stealth_ns.defence_eval.stealth.measure_stealth`; seconds at the demo's scale)."""
    lpips = lpips if lpips is not None else LazyLPIPS()
    ours, naive, coverage = {}, {}, {}
    for v in pair.views:
        pred = render(pair.poisoned, pair.cameras, v.index)
        ours[v.name] = illusion_metrics(pred, v.target, v.mask, lpips)
        naive[v.name] = illusion_metrics(render(pair.clean, pair.cameras, v.index), v.target, v.mask, lpips)
        covered = poison_coverage(pair.poisoned, pair.cameras, v.index)
        coverage[v.name] = None if covered is None else coverage_split(pred, v.target, v.mask, covered)
    per_view = {
        name: {
            **ours[name],
            **{f"clean_{k}": x for k, x in naive[name].items()},
            "poison_coverage": coverage[name],
        }
        for name in ours
    }
    out: dict[str, Any] = {}
    for (key, value), clean in zip(v_illusory(ours).items(), v_illusory(naive).values(), strict=True):
        out[f"v_illusory_{key}"], out[f"v_illusory_clean_{key}"] = value, clean
    test, test_clean = _held_out_metrics(pair.poisoned), _held_out_metrics(pair.clean)
    for key in ("psnr", "ssim", "lpips"):
        out[f"v_test_{key}"] = test[key]
        out[f"v_test_{key}_clean"] = test_clean[key]
    out["v_test_drop"] = out["v_test_psnr_clean"] - out["v_test_psnr"]
    out["attack_success"] = attack_success(out["v_illusory_psnr"], out["v_test_drop"])
    out["success_thresholds"] = success_verdicts(out["v_illusory_psnr"], out["v_test_drop"])
    lpips_left_out = out["v_illusory_lpips"] is None or out["v_test_lpips"] is None
    out["lpips_unavailable"] = (lpips.reason or "LPIPS unavailable") if lpips_left_out else None
    model = pair.poisoned.model
    out["n_gaussians"] = int(model.num_points)
    out["n_gaussians_clean"] = int(pair.clean.model.num_points)
    out["n_poison_gaussians"] = int(model.poison_mask.sum()) if hasattr(model, "poison_mask") else 0
    out["poisoned_views"] = list(per_view)
    out["v_illusory_per_view"] = per_view
    out["step"], out["step_clean"] = pair.poisoned.step, pair.clean.step
    # last: the defences fine-tune and prune the model (put back exactly after), nothing above sees it
    out["stealth"] = (
        measure_stealth(pair.poisoned, pair.record, out["attack_success"])
        if stealth
        else {"unavailable": "--no-stealth was given"}
    )
    out["stealthy_success"] = out["stealth"].get("stealthy_success")
    return out


def compare_runs(poisoned_config: Path, clean_config: Path, stealth: bool = True) -> dict[str, Any]:
    """Load a poisoned and a clean run of the same scene and return :func:`pair_metrics` (no files)."""
    return pair_metrics(RunPair.load(Path(poisoned_config), Path(clean_config)), stealth=stealth)


def neighbour_curve(pair: RunPair, angles: tuple[float, ...] = NEIGHBOUR_ANGLES) -> dict[str, Any]:
    """PSNR (dB) between the clean and the poisoned render of each poisoned view orbited by ``angles``
    (degrees) about the vertical axis through the scene centre; mean over poisoned views per angle."""
    c2ws = pair.cameras.camera_to_worlds
    center, up = scene_center(c2ws), scene_up(c2ws)
    per_view = {}
    for v in pair.views:
        base = c2ws[v.index].double().numpy()
        values = []
        for angle in angles:
            pose = rotate_pose(base, center, up, angle)
            values.append(
                psnr(
                    render(pair.poisoned, pair.cameras, v.index, pose),
                    render(pair.clean, pair.cameras, v.index, pose),
                )
            )
        per_view[v.name] = values
    mean = [float(np.mean([vals[i] for vals in per_view.values()])) for i in range(len(angles))]
    return {"angles_deg": list(angles), "psnr_mean": mean, "per_view": per_view}
