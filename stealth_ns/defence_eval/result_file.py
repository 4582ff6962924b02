"""``defend.json``, what ``stealth-ns defend`` writes: its name and the check that a folder holds one made
for a given run. Imports nothing heavy, so commands can check a ``--defend`` folder before torch loads."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.runs.paths import run_file

DEFEND_FILE = "defend.json"


def read_defend_result(defend_dir: Path, run: Path) -> dict[str, Any]:
    """The ``defend.json`` of ``defend_dir``, which must have been made for ``run`` (its folder,
    config.yml or PLY, as given on the command line). One-line StealthNSError when the folder holds no
    readable defend.json or it was made for another run."""
    path = Path(defend_dir) / DEFEND_FILE
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise StealthNSError(f"--defend {defend_dir}: no readable {DEFEND_FILE} ({err})") from None
    if not isinstance(result, dict) or not isinstance(result.get("run"), str):
        raise StealthNSError(f"--defend {defend_dir}: {DEFEND_FILE} does not say which run it was made for")
    if Path(result["run"]).resolve() != run_file(run).resolve():
        made_for = result["run"]
        raise StealthNSError(f"--defend {defend_dir} was made for {made_for}, not for the poisoned run {run}")
    return result
