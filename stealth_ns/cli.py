"""`stealth-ns` console script: tyro subcommands.

Each command's options (a dataclass with a ``main()``) live in the package of its concept; this module
maps the command words to them and dispatches. Every subcommand raises :class:`StealthNSError` for bad
input; ``run`` prints it (and a write the environment refused) as one line (``stealth-ns: error: ...``),
exit status 2, never a traceback.
"""

from __future__ import annotations

import sys

import tyro

from stealth_ns.bench.command_line import BenchAttack, BenchRaster, BenchScan, BenchTrain
from stealth_ns.datasets.command_line import CheckData, SeedPoints
from stealth_ns.defence_eval.command_line import Defend
from stealth_ns.demo import Demo
from stealth_ns.difficulty.rank import RankViews
from stealth_ns.foundation import deferred_compile
from stealth_ns.foundation.errors import StealthNSError, environment_error
from stealth_ns.poisoned_datasets.command_line import IpaPoison, PoisonDataset
from stealth_ns.report.command_line import Report
from stealth_ns.scan.command_line import Scan
from stealth_ns.scene_generator.command_line import MakeScene

# command words -> dataclass; each dataclass has a ``main()``. Kept as a plain table (not a
# tyro union) so that every command, nested ones included, gets its own --help.
COMMANDS: dict[str, type] = {
    "make-scene": MakeScene,
    "demo": Demo,
    "report": Report,
    "bench raster": BenchRaster,
    "bench attack": BenchAttack,
    "bench train": BenchTrain,
    "bench scan": BenchScan,
    "rank-views": RankViews,
    "seed-points": SeedPoints,
    "check-data": CheckData,
    "defend": Defend,
    "scan": Scan,
    "poison-dataset": PoisonDataset,
    "ipa-poison": IpaPoison,
}


def _usage() -> str:
    lines = [
        "usage: stealth-ns COMMAND [OPTIONS]   (stealth-ns COMMAND --help for its options)",
        "",
        "commands:",
    ]
    for name, cls in COMMANDS.items():
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        lines.append(f"  {name:<16} {doc}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    words = []
    while argv and not argv[0].startswith("-") and " ".join([*words, argv[0]]) in _command_prefixes():
        words.append(argv.pop(0))
    name = " ".join(words)
    if name not in COMMANDS:
        if not words and argv and argv[0] in ("-h", "--help"):
            print(_usage())
            return
        unknown = " ".join(words) or (argv[0] if argv else "")
        raise StealthNSError(
            f"unknown command {unknown!r}; commands: {', '.join(COMMANDS)}"
            if unknown
            else f"no command given; commands: {', '.join(COMMANDS)}"
        )
    tyro.cli(COMMANDS[name], args=argv, prog=f"stealth-ns {name}").main()


def _command_prefixes() -> set[str]:
    prefixes = set()
    for name in COMMANDS:
        parts = name.split()
        prefixes.update(" ".join(parts[: i + 1]) for i in range(len(parts)))
    return prefixes


def run(argv: list[str] | None = None) -> int:
    """The exit status of ``stealth-ns ARGV``: 0; 2 after one line (bad input, a refused write); 130."""
    deferred_compile.install()
    try:
        main(argv)
    except (StealthNSError, OSError) as err:  # OSError: a write the environment refused (full disk)
        line = err if isinstance(err, StealthNSError) else environment_error(err)
        if line is None:
            raise
        print(f"stealth-ns: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("stealth-ns: interrupted", file=sys.stderr)
        return 130
    return 0


def entrypoint() -> None:
    if status := run():
        sys.exit(status)


if __name__ == "__main__":
    entrypoint()
