"""``stealth-ns defend``: its options, as tyro parses them, and the command."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import tyro

from stealth_ns.defences.config import DefendConfig


@dataclass
class Defend:
    """Run defences against an attacked run: can the poison be found, and what does removing it cost?"""

    run: Path
    """config.yml (or run folder) of the attacked run."""
    output: Path = Path("stealth-defend")
    """Folder for defend.json, defend.md, the figures, the pruned runs (pruned/) and the retrained
    run (input-filter/)."""
    clean: Path | None = None
    """config.yml of a clean run of the same scene: its V-test and V-illusory as reference."""
    options: Annotated[DefendConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=DefendConfig)

    def main(self) -> None:
        from stealth_ns.defence_eval.arguments import check_arguments

        check_arguments(self.run, self.output, self.options, self.clean)  # before torch and nerfstudio load
        from stealth_ns.defence_eval.command import run_defend

        run_defend(self.run, self.output, self.options, self.clean)
        print(f"\nwrote {self.output / 'defend.json'}, {self.output / 'defend.md'} and the figures")
        print((self.output / "defend.md").read_text())
