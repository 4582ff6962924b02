"""The command lines of the README and the guides (docs/guides/*.md), read as the tests run them.

Every line of a ```` ```bash ```` block is a command a reader may paste; the tests run each of them
(tests/docs/test_guide_examples.py), in one workspace folder, the README first and then the guides in
:data:`GUIDE_ORDER`, each guide's commands with the files the earlier ones made. The conventions a page
follows (docs/design/doc_examples.md):

* a trailing ``\\`` joins the next line; ``#`` starts a comment line; ``# writes: PATH ...`` right after a
  command names the files it writes (globs allowed), which the test then finds;
* no shell syntax (pipes, ``&&``, variables): a line is one command, split as the shell would (shlex);
* commands are written at a user's scale; :func:`at_test_scale` shrinks them (sizes, iterations), always
  the same way, so a guide's command stays the one a reader runs.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GUIDES = ROOT / "docs" / "guides"
GUIDE_ORDER = (
    "make-scene", "check-data", "seed-points", "train", "viewer", "report", "rank-views", "defend",
    "scan", "poison-dataset", "ipa-poison", "bench",
)  # fmt: skip
"""The guides in the order their examples run (each may use what the earlier ones wrote)."""
PROGRAMS = ("stealth-ns", "ns-train", "ns-eval", "ns-viewer", "ns-export", "make")
"""Programs an example may run."""
NOT_RUN = {
    "source": "sets up the reader's shell",
    "pip": "an install step",
    "apt-get": "an install step",
    "sudo": "an install step",
}
"""First words of set-up lines that are shown but not run, with the reason."""
RUN_BY_CI = ("test", "docs", "lint", "env")
"""``make`` targets that .ci/run runs itself (``make test`` would run this test inside itself)."""
SHELL_SYNTAX = re.compile(r"(\|\||&&|[|;<>`]|\$\w|\$\{|\$\()")

SCENE_SIZE = {"object": "48x48"}
SCENE_VIEWS = {"object": "24"}
TEST_SIZE = "64x48"
TEST_VIEWS = "16"
TEST_ITERATIONS = "60"


@dataclass
class Example:
    """One command line of a page."""

    source: str
    """``PAGE:LINE`` where the command starts."""
    argv: list[str]
    writes: list[str] = field(default_factory=list)
    """Paths (globs) the page says the command writes, relative to the workspace."""

    @property
    def line(self) -> str:
        return shlex.join(self.argv)


def bash_blocks(markdown: str) -> list[tuple[int, list[str]]]:
    """``(first line number, lines)`` of each ```` ```bash ```` (or ``sh``, ``shell``) fenced block."""
    blocks, lines, start, fence = [], markdown.splitlines(), None, None
    for number, line in enumerate(lines, 1):
        stripped = line.strip()
        if fence is None:
            match = re.match(r"^(`{3,}|~{3,})\s*(bash|sh|shell)\s*$", stripped)
            if match:
                fence, start, body = match.group(1), number + 1, []
            elif re.match(r"^(`{3,}|~{3,})", stripped):
                fence, start, body = re.match(r"^(`{3,}|~{3,})", stripped).group(1), None, None
        elif stripped == fence:
            if start is not None:
                blocks.append((start, body))
            fence = None
        elif start is not None:
            body.append(line)
    if fence is not None:
        raise ValueError(f"a fenced block opened at line {start} is never closed")
    return blocks


def examples(markdown: str, page: str) -> list[Example]:
    """The commands of a page's bash blocks, with the ``# writes:`` lines that follow them."""
    found: list[Example] = []
    for start, body in bash_blocks(markdown):
        pending, first = "", None
        for offset, raw in enumerate(body):
            number, line = start + offset, raw.strip()
            if not pending and (not line or line.startswith("#")):
                if line.startswith("# writes:"):
                    if not found or found[-1].source.split(":")[0] != page:
                        raise ValueError(f"{page}:{number}: '# writes:' before any command")
                    found[-1].writes.extend(shlex.split(line[len("# writes:") :]))
                continue
            first = first or number
            if line.endswith("\\"):
                pending += line[:-1] + " "
                continue
            text, pending = pending + line, ""
            found.append(Example(f"{page}:{first}", _split(text, f"{page}:{first}")))
            first = None
        if pending:
            raise ValueError(f"{page}:{first}: the block ends inside a continued line")
    return found


def _split(text: str, where: str) -> list[str]:
    if SHELL_SYNTAX.search(text):
        raise ValueError(f"{where}: shell syntax in an example (one plain command a line): {text}")
    argv = shlex.split(text, comments=True)
    if not argv:
        raise ValueError(f"{where}: an empty command")
    if argv[0] not in PROGRAMS and argv[0] not in NOT_RUN:
        raise ValueError(f"{where}: {argv[0]!r} is not a program the examples run ({', '.join(PROGRAMS)})")
    if any(re.search(r"<[^>]+>", word) for word in argv):
        raise ValueError(f"{where}: a placeholder in an example (give a concrete path): {text}")
    return argv


def page_examples(page: Path) -> list[Example]:
    """The examples of one page, named by its path from the repository root."""
    return examples(page.read_text(encoding="utf-8"), str(page.relative_to(ROOT)))


def not_run_reason(argv: list[str]) -> str | None:
    """Why a line is shown but not run here (a set-up step, or a make target CI runs), else None."""
    if argv[0] in NOT_RUN:
        return NOT_RUN[argv[0]]
    if argv[0] == "make" and len(argv) > 1 and argv[1] in RUN_BY_CI:
        return f"make {argv[1]} is run by .ci/run"
    return None


def _set(argv: list[str], option: str, value: str, at: int | None = None) -> list[str]:
    """``argv`` with ``option value`` (replacing the value it has, else inserted at ``at`` or appended)."""
    argv = list(argv)
    for i, word in enumerate(argv):
        if word == option and i + 1 < len(argv):
            argv[i + 1] = value
            return argv
        if word.startswith(option + "="):
            argv[i] = f"{option}={value}"
            return argv
    words = [option, value]
    return argv[:at] + words + argv[at:] if at is not None else argv + words


def _preset(argv: list[str]) -> str:
    return argv[argv.index("--preset") + 1] if "--preset" in argv[:-1] else "orbit"


def at_test_scale(argv: list[str], workspace: Path, port: int = 0) -> list[str]:
    """The command as the test runs it: small sizes and few iterations, never anything else changed.

    make-scene: 64x48 (object 48x48), 16 views (object 24); ns-train: 60 iterations, the attack injected
    at step 20, no periodic full evaluation; demo, bench attack: 60 iterations; ipa-poison: 60 iterations,
    an attack epoch every 20; bench train: 3 steps after
    2 on a 64x48 scene; bench raster: --quick; ns-viewer: on 127.0.0.1 at ``port``; make demo: shortened
    and written into the workspace."""
    program, words = argv[0], argv[1:]
    command = " ".join(words[:2])
    if program == "stealth-ns" and words[:1] == ["make-scene"]:
        preset = _preset(argv)
        argv = _set(argv, "--resolution", SCENE_SIZE.get(preset, TEST_SIZE))
        return _set(argv, "--views", SCENE_VIEWS.get(preset, TEST_VIEWS))
    if program == "stealth-ns" and words[:1] == ["demo"]:
        return _set(argv, "--iterations", TEST_ITERATIONS)
    if program == "stealth-ns" and command == "bench attack":
        return _set(argv, "--iterations", TEST_ITERATIONS)
    if program == "stealth-ns" and command == "bench train":
        argv = _set(_set(argv, "--warmup", "2"), "--steps", "3")
        return argv if "--data" in argv else _set(argv, "--resolution", TEST_SIZE)
    if program == "stealth-ns" and words[:1] == ["ipa-poison"]:
        return _set(_set(argv, "--iterations", TEST_ITERATIONS), "--every", "20")
    if program == "stealth-ns" and command == "bench raster":
        return argv if "--quick" in argv else [*argv, "--quick"]
    if program == "ns-train":
        if "--vis" not in argv:
            raise ValueError(
                "an ns-train example must pass --vis tensorboard (the viewer waits after training)"
            )
        argv = _set(argv, "--max-num-iterations", TEST_ITERATIONS, at=2)
        argv = _set(argv, "--steps-per-eval-all-images", "100000", at=2)
        return _set(argv, "--pipeline.attack.injection-step", "20", at=2)
    if program == "ns-viewer":
        argv = _set(argv, "--viewer.websocket-host", "127.0.0.1")
        return _set(argv, "--viewer.websocket-port", str(port))
    if program == "make" and words[:1] == ["demo"]:
        return [
            "make", "-C", str(ROOT), "demo",
            f"DEMO_ARGS=--iterations {TEST_ITERATIONS} --output {workspace / 'demo-output'}",
        ]  # fmt: skip
    return argv
