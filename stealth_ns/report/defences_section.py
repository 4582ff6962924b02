"""The "Defences" section of ``report.html``, read from a ``stealth-ns defend`` folder of the poisoned run."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from stealth_ns.defence_eval.outputs import COLUMNS, best_cuts, table_rows
from stealth_ns.foundation.json_io import atomic_path


def report_section(result: dict[str, Any], defend_dir: Path, output: Path) -> dict[str, Any]:
    """The "Defences" section of ``report.html`` from the ``defend.json`` of a ``stealth-ns defend``
    folder (:func:`~stealth_ns.defence_eval.result_file.read_defend_result` checks that it is the poisoned
    run's): its table rows, and its figures copied to ``output/defences/`` (so the report folder stands
    alone)."""
    figures = {}
    (output / "defences").mkdir(parents=True, exist_ok=True)
    for key, name in (result.get("figures") or {}).items():
        if (Path(defend_dir) / name).is_file():
            with atomic_path(output / "defences" / name) as tmp:
                shutil.copy2(Path(defend_dir) / name, tmp)
            figures[key] = f"defences/{name}"
    return {
        "source": str(Path(defend_dir).resolve()),
        "defeat_rule": result["defeat_rule"],
        "header": list(COLUMNS),
        "rows": table_rows(result),
        "best": best_cuts(result),
        "figures": figures,
    }
