"""``stealth-ns report``: its options, as tyro parses them, and the command."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class Report:
    """Compare a poisoned run with a clean run of the same scene: report.json, report.html, PNGs."""

    poisoned: Path
    """config.yml (or run folder) of the attacked run, or a 3DGS PLY of a victim trained elsewhere
    (with --poisoned-data)."""
    clean: Path
    """config.yml (or run folder) of a clean run of the same scene (--pipeline.attack.enabled False), or a
    3DGS PLY (with --clean-data)."""
    output: Path = Path("stealth-report")
    """Folder to write report.json, report.html, the figures and images/."""
    defend: Path | None = None
    """Output folder of `stealth-ns defend --run POISONED`: adds a "Defences" section to report.html."""
    poisoned_data: Path | None = None
    """The dataset a --poisoned PLY was trained on (for a victim of poison-dataset: the poisoned copy)."""
    clean_data: Path | None = None
    """The dataset a --clean PLY was trained on."""
    stealth: bool = True
    """Measure the poisoned run's stealth: every post-hoc defence's AUROC, the V-illusory the strongest
    leaves at <= 0.5 dB of V-test, stealthy success (seconds at the demo's scale; --no-stealth skips it)."""

    def main(self) -> None:
        from stealth_ns.report.arguments import check_arguments

        check_arguments(self.poisoned, self.clean, self.output, self.defend)  # before torch loads
        from stealth_ns.report.write import summary_lines, write_report

        data = (self.poisoned_data, self.clean_data)
        report = write_report(self.poisoned, self.clean, self.output, self.defend, self.stealth, *data)
        print("\n".join(summary_lines(report, self.output)))
