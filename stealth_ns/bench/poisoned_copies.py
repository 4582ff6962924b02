"""The bench's poisoned datasets: the copies its data-only and IPA-Splat runs train on.

A Table 1-3 row of a dataset attack (``RunSpec.poisoning``) is two steps: ``stealth-ns poison-dataset``
or ``stealth-ns ipa-poison`` writes a poisoned copy of the scene into ``OUTPUT/poisoned/EXP/NAME``, then
a plain victim run (attack off) trains on it like any other run of the plan. A copy is made once: the
file ``NAME.poison.json`` beside it records what it was made from, and a copy whose record matches is
reused (its victim run too, whose identity carries the copy's).
"""

from __future__ import annotations

import hashlib
import json
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from stealth_ns.attack.normal_draw import NOISE_GENERATOR
from stealth_ns.attack.options import STEALTH_NS, AttackSettings, command_options
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import write_json_atomic
from stealth_ns.poisoned_datasets.config import IPAConfig, data_only_attack_defaults
from stealth_ns.poisoned_datasets.dataset_copy import RECORD_DIR, RECORD_FILE
from stealth_ns.runs import training as runs
from stealth_ns.runs.training import bin_path

Poisoning = Literal["data-only", "ipa"]
COMMANDS: dict[str, str] = {"data-only": "poison-dataset", "ipa": "ipa-poison"}
LOG = "poison.log"


@dataclass(frozen=True)
class PoisonJob:
    """How one bench run's poisoned copy is made."""

    kind: Poisoning
    source: Path
    """The scene's dataset (a generated scene, a dataset folder or its seeded copy)."""
    output: Path
    """The poisoned copy."""
    view: str | None
    """The poisoned (backdoor) view; None: the attack's default, the median-indexed frame."""
    attack: AttackSettings
    """More attack settings of the poisoning command (``multi_view=2``: ``--multi-view 2``)."""
    method: str
    seed: int
    iterations: int
    source_id: str | None = None
    """The source in the identity, as the scene's other runs name it (a folder: ``NAME:CONTENT-HASH``);
    None: the source folder's name (a generated scene's holds its seed and options). Never a path, so
    a moved output folder keeps its copies."""

    def identity(self) -> dict[str, Any]:
        """What a copy on disk must have been made from to be reused."""
        identity: dict[str, Any] = {
            "kind": self.kind,
            "source": self.source_id or self.source.name,
            "view": self.view,
            "args": list(self.args),
            "method": self.method,
            "seed": self.seed,
        }
        if self.kind == "ipa":  # the attacker trains; data-only only sets up the model
            identity["iterations"] = self.iterations
        if self.kind == "data-only" and self.attack.config(data_only_attack_defaults()).view_noise:
            identity["view_noise"] = NOISE_GENERATOR  # static noise: a copy with other draws is made again
        return identity

    @property
    def args(self) -> tuple[str, ...]:
        """:attr:`attack` as the poisoning command's options (``--multi-view 2``)."""
        return command_options(self.attack, STEALTH_NS)

    @property
    def scene_id(self) -> str:
        """The victim run's scene in its identity: changes whenever the copy would be made differently."""
        digest = hashlib.sha256(json.dumps(self.identity(), sort_keys=True).encode()).hexdigest()
        return f"poisoned-{self.kind}:{digest[:16]}"

    @property
    def marker(self) -> Path:
        return self.output.with_name(self.output.name + ".poison.json")

    @property
    def log(self) -> Path:
        return self.output.with_name(self.output.name + "." + LOG)

    def ready(self) -> bool:
        """The copy exists, is complete, and was made from this job's settings."""
        try:
            made = json.loads(self.marker.read_text(encoding="utf-8"))
            record = json.loads((self.output / RECORD_DIR / RECORD_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        complete = bool((record.get("poisoned_dataset") or {}).get("complete"))
        return complete and made == self.identity()

    def command(self) -> list[str]:
        """The ``stealth-ns`` command that makes the copy (``--overwrite`` replaces an earlier copy only)."""
        cmd = [bin_path("stealth-ns"), COMMANDS[self.kind], "--data", str(self.source)]
        cmd += [
            "--output",
            str(self.output),
            "--overwrite",
            "--method",
            self.method,
            "--seed",
            str(self.seed),
        ]
        if self.kind == "ipa":
            cmd += ["--iterations", str(self.iterations)]
            if self.iterations <= IPAConfig.every:
                # a short bench (tests, --iterations <= 200): one attack epoch half-way, not none
                cmd += ["--every", str(max(1, self.iterations // 2))]
        if self.view is not None:
            cmd += ["--views", self.view]
        return [*cmd, *self.args]

    def display_command(self) -> str:
        """:meth:`command` as a shell line, with ``stealth-ns`` instead of its full path."""
        return shlex.join(["stealth-ns", *self.command()[1:]])

    def make(self) -> None:
        """Make the copy (output to :attr:`log`, as the bench's trainings: :func:`runs.run_command`);
        RuntimeError with the command's last error line."""
        try:
            runs.run_command(self.command(), self.log, stream=False)
        except StealthNSError:
            output = self.log.read_text(errors="replace").splitlines()[1:]  # after the "$ command" line
            lines = [ln for ln in output if ln.strip()]
            last = next((ln for ln in reversed(lines) if "error" in ln.lower()), lines[-1] if lines else "")
            raise RuntimeError(f"{COMMANDS[self.kind]} failed ({last.strip()}; log: {self.log})") from None
        write_json_atomic(self.marker, self.identity())


def ensure_copies(jobs: dict[str, PoisonJob], echo: Any = print) -> dict[str, str]:
    """Make every copy of ``jobs`` (run key -> job) that is not ready; returns run key -> error."""
    errors = {}
    for key, job in jobs.items():
        if job.ready():
            continue
        what = "IPA-Splat (the attacker trains first)" if job.kind == "ipa" else "data-only StealthAttack"
        echo(f"poisoning {key}: {what} -> {job.output} (log: {job.log})", flush=True)
        try:
            job.make()
        except (RuntimeError, OSError) as err:
            errors[key] = f"its poisoned dataset could not be made: {err}"
            echo(f"FAILED {key}: {errors[key]}", flush=True)
    return errors
