"""Console scripts as a user runs them: registration with nerfstudio, help, one-line errors."""

from __future__ import annotations

import json
import platform
import re
import subprocess
import sys

import pytest
from conftest import run_cli


def test_ns_train_lists_the_methods():
    out = run_cli("ns-train", "--help").stdout
    assert "stealth-splat" in out and "stealth-splat-lite" in out


REPORT = ["report", "--poisoned", "{tmp}/run", "--clean", "{tmp}/c", "--output", "{tmp}/r"]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["poison-dataset", "--data", "{tmp}", "--output", "{tmp}/o", "--t-min", "-1"], "--t-min"),
        (["ipa-poison", "--data", "{tmp}", "--output", "{tmp}/o", "--epsilon", "0"], "--epsilon"),
        (["ipa-poison", "--data", "{tmp}", "--output", "{tmp}/o", "--multi-view", "9"], "--multi-view"),
        (["defend", "--run", "{tmp}/run/config.yml", "--output", "{tmp}/run/d"], "inside the run folder"),
        (["scan", "--model", "{tmp}/run", "--output", "{tmp}/run/scan"], "inside the run folder"),
        (["bench", "train", "--preset", "nope"], "--preset 'nope'"),
        (
            ["report", "--poisoned", "{tmp}/run", "--clean", "{tmp}/run/config.yml", "--output", "{tmp}/r"],
            "is the poisoned run itself",
        ),
        (
            ["report", "--poisoned", "{tmp}/nope", "--clean", "{tmp}/c", "--output", "{tmp}/r"],
            "--poisoned {tmp}/nope: no run config",
        ),
        ([*REPORT, "--defend", "{tmp}/run"], "no readable defend.json"),
        ([*REPORT, "--defend", "{tmp}/d"], "was made for {tmp}/other/config.yml, not for the poisoned run"),
    ],
    ids=[
        "poison-dataset",
        "ipa-epsilon",
        "ipa-views",
        "defend",
        "scan",
        "bench-train",
        "report-same-run",
        "report-missing-run",
        "report-no-defend-json",
        "report-defend-of-another-run",
    ],
)
def test_bad_arguments_are_refused_before_torch_and_nerfstudio_load(tmp_path, args, needle):
    """A mistyped option or output folder costs a second, not the 4-15 s of importing torch and
    nerfstudio first (docs/design/testing.md)."""
    for run in ("run", "c"):
        (tmp_path / run).mkdir()
        (tmp_path / run / "config.yml").write_text("x: 1\n")
    (tmp_path / "d").mkdir()  # a defend folder of another run
    (tmp_path / "d" / "defend.json").write_text(json.dumps({"run": str(tmp_path / "other" / "config.yml")}))
    (tmp_path / "r").mkdir()  # an earlier report, kept when the next one is refused
    (tmp_path / "r" / "report.html").write_text("earlier")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    needle = needle.replace("{tmp}", str(tmp_path))
    code = (
        "import sys\nfrom stealth_ns.cli import main\n"
        "from stealth_ns.foundation.errors import StealthNSError\n"
        f"try:\n    main({argv!r})\n"
        "except StealthNSError as err:\n"
        "    print(sorted(m for m in ('torch', 'nerfstudio') if m in sys.modules), err)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.startswith("[] ") and needle in proc.stdout, proc.stdout + proc.stderr[-2000:]
    assert not (tmp_path / "run" / "d").exists() and not (tmp_path / "run" / "scan").exists()
    assert (tmp_path / "r" / "report.html").read_text() == "earlier"


def test_stealth_ns_help_lists_commands():
    out = run_cli("stealth-ns", "--help").stdout
    for command in ("make-scene", "demo", "bench raster"):
        assert command in out


def test_unknown_command_is_one_line_error():
    proc = run_cli("stealth-ns", "frobnicate", check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "unknown command 'frobnicate'" in proc.stderr


@pytest.mark.parametrize(
    "args",
    [["scan", "--model", "{tmp}", "--output", "{tmp}/scan"], ["defend", "--help"], ["report", "--nope"]],
)
def test_commands_run_in_the_tests_process_as_the_console_script_runs_them(tmp_path, args):
    """conftest's in-process runner (most tests of report, defend, scan and poison-dataset use it) gives
    the console script's exit status, stdout and stderr."""
    (tmp_path / "config.yml").write_text("x: 1\n")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    here, script = (run_cli("stealth-ns", *argv, check=False, in_process=flag) for flag in (True, False))
    assert here.returncode == script.returncode and (here.returncode != 0 or args[-1] == "--help")

    def words(text: str) -> list[str]:  # rich draws its boxes in ASCII into a StringIO
        return re.findall(r"-*\w[\w.:/-]*", text)

    assert words(here.stdout) == words(script.stdout) and words(here.stdout + here.stderr)
    assert words(here.stderr) == words(script.stderr)


def test_bench_raster_quick_writes_json(tmp_path):
    path = tmp_path / "bench.json"
    run_cli("stealth-ns", "bench", "raster", "--quick", "--json", str(path))
    data = json.loads(path.read_text())
    (case_cpp, case_torch) = sorted(data["cases"], key=lambda c: c["backend"])
    for case in (case_cpp, case_torch):
        assert {
            "name",
            "n_gaussians",
            "width",
            "height",
            "backend",
            "forward_ms",
            "forward_backward_ms",
        } <= set(case)
        # both measured (their ratio is a benchmark figure, not behaviour: a loaded machine can invert it)
        assert case["forward_backward_ms"] > 0 and case["forward_ms"] > 0
    # timed as a CPU training runs: freed memory kept for reuse (glibc; elsewhere nothing to set)
    glibc = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"
    assert data["settings"]["freed_memory_kept"] is glibc
    # the speed-ups are the reference's time over the compiled one's, of the rows written beside them
    name = case_cpp["name"]
    for key, ms in (("speedup_fwd_bwd", "forward_backward_ms"), ("speedup_fwd", "forward_ms")):
        assert data[key][name] == pytest.approx(case_torch[ms] / case_cpp[ms], rel=1e-6)


def test_bench_raster_json_into_missing_folder_is_an_error(tmp_path):
    proc = run_cli(
        "stealth-ns", "bench", "raster", "--quick", "--json", str(tmp_path / "nope" / "b.json"), check=False
    )
    assert proc.returncode == 2 and "does not exist" in proc.stderr
