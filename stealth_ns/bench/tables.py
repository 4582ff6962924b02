"""The paper-shaped tables of a benchmark: numbers from the runs' metrics (:func:`table_data`) and
``tables.md`` (:func:`render_markdown`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stealth_ns.defence_eval.rule import DEFEAT_RULE
from stealth_ns.defence_eval.stealth import KEY_DETECTORS
from stealth_ns.method_configs.attack_experiments import (
    TableSpec,
)

SUCCESS_RULE = "V-illusory PSNR > 25 dB and V-test PSNR drop <= 3 dB"
NOT_IMPLEMENTED = (
    "Not implemented in stealth-ns: the paper's IPA-NeRF (Nerfacto) and IPA-NeRF (Instant-NGP) "
    "baselines (NeRF methods; no rows for them), and its datasets (Mip-NeRF 360, Tanks & Temples, "
    "Free), replaced by generated scenes and dataset folders (the real capture fox where present)."
)


METRIC_NAMES = (("psnr", "PSNR↑", 2), ("ssim", "SSIM↑", 3), ("lpips", "LPIPS↓", 3))
FAMILY_LABELS = {"v_illusory": "V-illusory", "v_test": "V-test"}
MISSING = "n/a"


def _metric_key(family: str, metric: str, naive: bool) -> str:
    if family == "v_illusory":
        return f"v_illusory_clean_{metric}" if naive else f"v_illusory_{metric}"
    return f"v_test_{metric}_clean" if naive else f"v_test_{metric}"


def table_data(table: TableSpec, runs: dict[str, dict[str, Any]], scenes: Sequence[str]) -> dict[str, Any]:
    """A table's header and numbers from the runs' metrics (``"n/a"`` where a run has none).

    Only the column groups of ``scenes`` are kept. Values are floats, None (a metric the run
    could not compute, e.g. LPIPS without its weights) or ``"n/a"`` (run failed or missing).
    """
    groups = [(i, g) for i, g in enumerate(table.groups) if g.scene in scenes]
    multi_group = len(table.groups) > 1  # label the scene even when --scenes keeps one group
    columns: list[dict[str, Any]] = []
    for _, g in groups:
        for family in g.metrics:
            for metric, label, digits in METRIC_NAMES:
                parts = [g.label if multi_group else "", FAMILY_LABELS[family], label]
                columns.append({"label": " ".join(p for p in parts if p), "metric": metric, "digits": digits})
    rows = []
    lpips_notes: set[str] = set()
    missing_runs: set[str] = set()
    for row in table.rows:
        values: list[Any] = []
        successes: list[bool] = []
        for i, g in groups:
            key = f"{g.scene}/{row.runs[i]}"
            metrics = (runs.get(key) or {}).get("metrics")
            if not isinstance(metrics, dict):
                missing_runs.add(key)
            elif metrics.get("lpips_unavailable"):
                lpips_notes.add(str(metrics["lpips_unavailable"]))
            if isinstance(metrics, dict) and not row.naive:
                successes.append(bool(metrics.get("attack_success")))
            for family in g.metrics:
                for metric, _, _ in METRIC_NAMES:
                    if not isinstance(metrics, dict):
                        values.append(MISSING)
                    else:
                        v = metrics.get(_metric_key(family, metric, row.naive))
                        values.append(float(v) if isinstance(v, (int, float)) else None)
        entry: dict[str, Any] = {
            "keys": list(row.keys),
            "runs": [f"{g.scene}/{row.runs[i]}" for i, g in groups],
            "naive": row.naive,
            "values": values,
        }
        if table.asr:
            entry["asr"] = f"{sum(successes)}/{len(successes)}" if successes else MISSING
        rows.append(entry)
    return {
        "number": table.number,
        "title": table.title,
        "key_header": list(table.key_header),
        "columns": columns,
        "asr": table.asr,
        "rows": rows,
        "notes": list(table.notes),
        "lpips_unavailable": sorted(lpips_notes),
        "missing_runs": sorted(missing_runs),
    }


def fmt_value(value: Any, digits: int) -> str:
    if value == MISSING:
        return MISSING
    if value is None:
        return "–"
    text = f"{float(value):.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text  # no "-0.00"


def render_table(data: dict[str, Any]) -> str:
    """One table of :func:`table_data` as markdown; the best attack value of each column in bold."""
    columns = data["columns"]
    header = [*data["key_header"], *(c["label"] for c in columns)]
    if data["asr"]:
        header.append(f"ASR ({SUCCESS_RULE})")
    best: list[str | None] = []
    for j, col in enumerate(columns):
        vals = [r["values"][j] for r in data["rows"] if not r["naive"] and isinstance(r["values"][j], float)]
        texts = {fmt_value(v, col["digits"]) for v in vals}
        if len(texts) < 2:  # one row, or all equal: nothing to single out
            best.append(None)
            continue
        pick = min(vals) if col["metric"] == "lpips" else max(vals)
        best.append(fmt_value(pick, col["digits"]))
    lines = [f"## Table {data['number']}: {data['title']}", ""]
    lines.append("| " + " | ".join(header) + " |")
    lines.append(
        "|"
        + "|".join([":--"] * len(data["key_header"]) + ["--:"] * (len(header) - len(data["key_header"])))
        + "|"
    )
    for r in data["rows"]:
        cells = list(r["keys"])
        for j, col in enumerate(columns):
            text = fmt_value(r["values"][j], col["digits"])
            cells.append(
                f"**{text}**" if not r["naive"] and best[j] is not None and text == best[j] else text
            )
        if data["asr"]:
            cells.append(r["asr"])
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    notes = list(data["notes"])
    for reason in data["lpips_unavailable"]:
        notes.append(f"LPIPS shown as –: {reason}")
    if data["missing_runs"]:
        notes.append(
            f"{MISSING}: no numbers for {', '.join(data['missing_runs'])} (run failed, interrupted or not "
            "run yet; see results.json and the run's ns-train.log)"
        )
    lines += [f"- {note}" for note in notes]
    return "\n".join(lines) + "\n"


def _runs_table(runs: dict[str, dict[str, Any]]) -> str:
    header = [
        "Run", "Settings", "Poisoned view(s)", "V-illusory PSNR", "V-test PSNR (clean → poisoned)",
        "Drop", "Success", "Gaussians (poison)", "Training", "Median step", "This invocation",
    ]  # fmt: skip
    lines = ["## All runs", "", "| " + " | ".join(header) + " |", "|" + "|".join([":--"] * len(header)) + "|"]
    for key, e in runs.items():
        m = e.get("metrics") if isinstance(e.get("metrics"), dict) else None
        seconds = e.get("train_seconds")
        train_time = f"{seconds / 60:.1f} min" if isinstance(seconds, (int, float)) else MISSING
        if m is not None:
            views = ", ".join(m.get("poisoned_views") or [])
            test = f"{fmt_value(m.get('v_test_psnr_clean'), 2)} → {fmt_value(m.get('v_test_psnr'), 2)}"
            gauss = f"{m.get('n_gaussians', MISSING)} ({m.get('n_poison_gaussians', MISSING)})"
            cells = [
                views, fmt_value(m.get("v_illusory_psnr"), 2), test, fmt_value(m.get("v_test_drop"), 2),
                "yes" if m.get("attack_success") else "no", gauss,
            ]  # fmt: skip
        elif e.get("clean"):
            cells = ["–", "–", "–", "–", "–", "–"]
        else:
            cells = [e.get("kde_view") or MISSING, MISSING, MISSING, MISSING, MISSING, MISSING]
        status = e.get("status", MISSING)
        if e.get("metrics_error"):
            status += " (metrics failed)"
        step = e.get("median_step_ms")
        step_time = f"{step:.0f} ms" if isinstance(step, (int, float)) else MISSING
        row = [key, e.get("label", ""), *cells, train_time, step_time, status]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def stealth_table(runs: dict[str, dict[str, Any]]) -> str:
    """Markdown: every attacked run with metrics, its success and its stealth under the post-hoc
    defences (:mod:`stealth_ns.defence_eval.stealth`); empty when no run has metrics."""
    header = [
        "Run", "V-illusory PSNR", "Drop", "Success", *(f"AUROC {n}" for n in KEY_DETECTORS),
        "Strongest defence (≤ 0.5 dB)", "V-illusory after", "Defeated by", "Stealthy success",
    ]  # fmt: skip
    rows = []
    for key, e in runs.items():
        m = e.get("metrics")
        if e.get("clean") or not isinstance(m, dict):
            continue
        s = (
            m.get("stealth")
            if isinstance(m.get("stealth"), dict)
            else {"unavailable": "metrics from before the stealth was measured"}
        )
        cells = [key, fmt_value(m.get("v_illusory_psnr"), 2), fmt_value(m.get("v_test_drop"), 2)]
        cells.append("yes" if m.get("attack_success") else "no")
        if s.get("unavailable"):
            cells += [MISSING] * (len(KEY_DETECTORS) + 3) + [f"{MISSING} ({s['unavailable']})"]
        else:
            cells += [fmt_value(s["auroc"].get(n), 3) for n in KEY_DETECTORS]
            cells += [s.get("strongest_defence") or "–", fmt_value(s.get("v_illusory_after_strongest"), 2)]
            cells += [", ".join(s["defeated_by"]) or "none", "yes" if s["stealthy_success"] else "no"]
        rows.append("| " + " | ".join(cells) + " |")
    if not rows:
        return ""
    lines = ["## Stealth under the post-hoc defences", ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "|".join([":--"] + ["--:"] * (len(header) - 1)) + "|"]
    lines += [*rows, ""]
    lines.append(
        f"- A defence defeats an attack when {DEFEAT_RULE}, at its own rule or at a fixed share of its most "
        "suspicious Gaussians; stealthy success: the paper's success and no post-hoc defence defeats it. "
        "AUROC against the poison tag (– for a victim of a poisoned dataset, which has none)."
    )
    return "\n".join(lines) + "\n"


def _scene_text(name: str, scene: dict[str, Any]) -> str:
    sizes = [scene["resolution"]] if scene.get("resolution") else scene.get("resolutions") or []
    size = " / ".join("x".join(map(str, s)) for s in sizes) or "?"
    where = "" if scene.get("source", "preset") == "preset" else f"folder {scene.get('path')}, "
    return f"{name} ({where}{size}, {scene.get('views') or '?'} views)"


def _executor_text(executor: Any) -> str:
    """A sentence for tables.md when the runs trained as Ray tasks (nothing for local runs)."""
    if not isinstance(executor, dict) or executor.get("name") != "ray":
        return ""
    amounts = {k: executor.get(f"{k.lower()}s_per_run") for k in ("CPU", "GPU")}
    per_run = [f"{v:g} {k}" for k, v in amounts.items() if isinstance(v, (int, float))]
    return (
        f" Trained as Ray tasks on a cluster of {executor.get('nodes', '?')} node(s) "
        f"({', '.join(per_run) or '?'} per run); the device above is the driver's, each run's node is "
        "in results.json."
    )


def render_markdown(results: dict[str, Any]) -> str:
    """``tables.md``: a header (method, environment, what is not implemented), the tables, all runs."""
    env = results.get("environment", {})
    scenes = results.get("scenes", {})
    scene_text = ", ".join(_scene_text(name, s) for name, s in scenes.items())
    lines = [
        "# StealthAttack experiments: the paper's tables on generated scenes and dataset folders",
        "",
        f"Produced by `stealth-ns bench attack` on {env.get('date', '?')}: method "
        f"{env.get('method', '?')}, {env.get('iterations', '?')} iterations, seed {env.get('seed', '?')}, "
        f"device {env.get('device', '?')} ({env.get('cpu_count', '?')} CPU cores); torch "
        f"{env.get('torch', '?')}, nerfstudio {env.get('nerfstudio', '?')}, "
        f"gsplat {env.get('gsplat') or '–'}, numpy {env.get('numpy', '?')}. Scenes: {scene_text or '?'}."
        + _executor_text(env.get("executor")),
        "",
        "Every number is measured from the runs listed at the end; `results.json` next to this file has "
        "all of them, with timings. V-illusory: masked metrics of the poisoned view(s) against the "
        "illusion target; V-test: held-out views against the clean images. Attack success: "
        f"{SUCCESS_RULE} against the clean run of the same scene.",
        "",
        results.get("not_implemented", NOT_IMPLEMENTED),
        "",
    ]
    if not results.get("complete", True):
        lines += ["**Incomplete**: some runs have not finished (or failed); their cells read n/a.", ""]
    if results.get("only"):
        lines += [
            f"Only the runs whose name contains {' or '.join(results['only'])} were planned (`--only`), "
            "with their clean baselines: the other cells read n/a.",
            "",
        ]
    for number in sorted(results.get("tables", {}), key=int):
        lines.append(render_table(results["tables"][number]))
    if results.get("table_d"):
        from stealth_ns.bench.defence_table import render_table as render_defence_table

        lines.append(render_defence_table(results["table_d"]))
    stealth = stealth_table(results.get("runs", {}))
    if stealth:
        lines.append(stealth)
    lines.append(_runs_table(results.get("runs", {})))
    return "\n".join(lines)
