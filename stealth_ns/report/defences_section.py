"""The "Defences" section of ``report.html``, read from a ``stealth-ns defend`` folder of the poisoned run."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from stealth_ns.defend.outputs import COLUMNS, DEFEND_FILE, best_cuts, table_rows
from stealth_ns.errors import StealthNSError


def report_section(defend_dir: Path, output: Path, poisoned_run: str) -> dict[str, Any]:
    """The "Defences" section of ``report.html`` from a ``stealth-ns defend`` folder: its table rows,
    and its figures copied to ``output/defences/`` (so the report folder stands alone).

    StealthNSError when the folder has no defend.json or it was made for another run."""
    path = Path(defend_dir) / DEFEND_FILE
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise StealthNSError(f"--defend {defend_dir}: no readable defend.json ({err})") from None
    if Path(result.get("run", "")).resolve() != Path(poisoned_run).resolve():
        raise StealthNSError(
            f"--defend {defend_dir} was made for {result.get('run')}, not for the poisoned run {poisoned_run}"
        )
    figures = {}
    (output / "defences").mkdir(parents=True, exist_ok=True)
    for key, name in (result.get("figures") or {}).items():
        if (Path(defend_dir) / name).is_file():
            shutil.copy2(Path(defend_dir) / name, output / "defences" / name)
            figures[key] = f"defences/{name}"
    return {
        "source": str(Path(defend_dir).resolve()),
        "defeat_rule": result["defeat_rule"],
        "header": list(COLUMNS),
        "rows": table_rows(result),
        "best": best_cuts(result),
        "figures": figures,
    }
