"""Every command line of the README and the guides, run as a reader runs it (tests/doc_examples.py):
the README first, then the guides in their order, all in one workspace; each command exits 0 without a
traceback and writes the files its page names. A line run already (the same command on an earlier page)
is not run twice."""

from __future__ import annotations

import glob
import os
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest
from conftest import BIN, IN_PROCESS_COMMANDS, _run_here, free_port, stop_process
from doc_examples import GUIDE_ORDER, GUIDES, ROOT, Example, at_test_scale, not_run_reason, page_examples

PAGES = ("README.md", *(f"docs/guides/{name}.md" for name in GUIDE_ORDER))
COMMAND_TIMEOUT = 900


class Workspace:
    """The folder the pages' commands share, what ran in it and which pages are done."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.ran: set[str] = set()  # the command lines run so far
        self.done: dict[str, str | None] = {}  # page -> None when all its commands passed, else the failure

    def run_page(self, page: str) -> None:
        for earlier in PAGES[: PAGES.index(page)]:
            if earlier not in self.done:
                self._run_recorded(earlier)
            if self.done[earlier] is not None:
                pytest.fail(f"{page} needs what {earlier} makes, and {earlier} failed: {self.done[earlier]}")
        self._run_recorded(page)
        if self.done[page] is not None:
            pytest.fail(self.done[page])

    def _run_recorded(self, page: str) -> None:
        try:
            for example in page_examples(ROOT / page):
                self.run(example)
        except (AssertionError, ValueError, subprocess.TimeoutExpired) as err:
            self.done[page] = str(err)
            return
        self.done[page] = None

    def run(self, example: Example) -> None:
        if not_run_reason(example.argv) or example.line in self.ran:
            return
        self.ran.add(example.line)
        argv = at_test_scale(example.argv, self.folder, free_port())
        if argv[0] == "ns-viewer":
            self._serve(argv, example)
        else:
            proc = self._run(argv)
            assert proc.returncode == 0, (
                f"{example.source}: {example.line} exited {proc.returncode} (run as {' '.join(argv)})\n"
                f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
            )
            assert "Traceback" not in proc.stderr, f"{example.source}: {example.line}\n{proc.stderr[-3000:]}"
        for path in example.writes:
            assert glob.glob(str(self.folder / path)), (
                f"{example.source}: {example.line} should write {path}; the workspace has "
                f"{sorted(str(p.relative_to(self.folder)) for p in self.folder.rglob('*'))[:60]}"
            )

    def _run(self, argv: list[str]) -> subprocess.CompletedProcess:
        if argv[0] == "stealth-ns" and argv[1:2] and argv[1] in IN_PROCESS_COMMANDS:
            here = os.getcwd()
            os.chdir(self.folder)
            try:
                return _run_here(argv[1:])
            finally:
                os.chdir(here)
        program = str(BIN / argv[0]) if (BIN / argv[0]).exists() else argv[0]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        return subprocess.run(
            [program, *argv[1:]], cwd=self.folder, capture_output=True, text=True, env=env,
            timeout=COMMAND_TIMEOUT, stdin=subprocess.DEVNULL,
        )  # fmt: skip

    def _serve(self, argv: list[str], example: Example) -> None:
        """Start the viewer, wait until it answers HTTP, stop it."""
        port = argv[argv.index("--viewer.websocket-port") + 1]
        log = self.folder / f"ns-viewer-{port}.log"
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "TORCHDYNAMO_DISABLE": "1"}
        with open(log, "w") as out:
            proc = subprocess.Popen(
                [str(BIN / argv[0]), *argv[1:]], cwd=self.folder, stdout=out, stderr=subprocess.STDOUT,
                env=env, stdin=subprocess.DEVNULL,
            )  # fmt: skip
        try:
            deadline = time.time() + 180
            while time.time() < deadline:
                assert proc.poll() is None, (
                    f"{example.source}: {example.line} exited:\n{log.read_text()[-3000:]}"
                )
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=2) as response:
                        if response.status == 200:
                            return
                except OSError:
                    time.sleep(1)
            raise AssertionError(f"{example.source}: {example.line} did not serve in 180 s")
        finally:
            stop_process(proc)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Workspace:
    return Workspace(tmp_path_factory.mktemp("docs-workspace"))


def test_every_guide_is_in_the_run_order():
    pages = {p.stem for p in GUIDES.glob("*.md")} - {"index"}
    assert pages == set(GUIDE_ORDER), f"guides not in GUIDE_ORDER: {pages - set(GUIDE_ORDER)}; " \
        f"missing: {set(GUIDE_ORDER) - pages}"  # fmt: skip
    for name in GUIDE_ORDER:
        assert page_examples(GUIDES / f"{name}.md"), f"docs/guides/{name}.md has no example"


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES)
def test_the_examples_of(page: str, workspace: Workspace):
    workspace.run_page(page)
