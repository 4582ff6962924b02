"""``stealth-ns scan`` and ``bench scan`` write only inside --output (never through a symbolic link, never
over their input or a file they did not write, with a record of what they wrote), check their inputs
before anything loads, and give no verdict on a model that does not sit on the cameras (issue 57); a
model with a few broken rows is scanned without them (issue 78).
Every test hashes what lies outside --output (link targets, the model, the run, the dataset) before
and after."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from stealth_ns.foundation.errors import StealthNSError


def digest(path: Path) -> dict[str, str]:
    """SHA-256 of a file, or of every file under a folder (links not followed), by relative path."""
    path = Path(path)
    if path.is_file():
        return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    return {
        p.relative_to(path).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(path.rglob("*"))
        if p.is_file() and not p.is_symlink()
    }


def stealth_ns(*args: object) -> None:
    from stealth_ns.cli import main

    main([str(a) for a in args])


def refused(needle: str, *args: object) -> str:
    """The one-line StealthNSError that ``stealth-ns ARGS`` raises (it must contain ``needle``)."""
    with pytest.raises(StealthNSError, match=re.escape(needle)) as info:
        stealth_ns(*args)
    assert "\n" not in str(info.value)
    return str(info.value)


@pytest.fixture(scope="module")
def clean_ply(tiny_run_pair, tmp_path_factory) -> Path:
    """The tiny clean run's Gaussians as a PLY in nerfstudio's frame (as ns-export writes it)."""
    from stealth_ns.gaussians.ply import write_gaussian_ply
    from stealth_ns.method.model_cloud import cloud_of_model
    from stealth_ns.runs.loaded import load_run

    cloud = cloud_of_model(load_run(tiny_run_pair[1]).model)
    cloud.extra.clear()
    path = tmp_path_factory.mktemp("plys") / "clean.ply"
    write_gaussian_ply(path, cloud)
    return path


# ------------------------------------------------------------------ scan: links and inputs
def test_scan_never_writes_through_a_link(tiny_run_pair, tiny_orbit_scene, tmp_path):
    clean = tiny_run_pair[1]
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "pictures").mkdir(parents=True)
    (elsewhere / "precious.ply").write_bytes(b"the user's own model")
    (elsewhere / "pictures" / "a.png").write_bytes(b"a picture")
    outside = {p: digest(p) for p in (elsewhere, clean.parent, tiny_orbit_scene)}
    links = {
        "cleaned.ply": elsewhere / "precious.ply",
        "scan.json": elsewhere / "precious.ply",
        "images": elsewhere / "pictures",
        "cleaned": elsewhere / "pictures",
    }
    for name, target in links.items():
        out = tmp_path / f"out-{name}"
        out.mkdir()
        (out / name).symlink_to(target)
        message = refused("is a symbolic link", "scan", "--model", clean, "--output", out)
        assert str(out / name) in message
        assert [p.name for p in out.iterdir()] == [name]  # nothing written
    assert {p: digest(p) for p in outside} == outside


def test_scan_never_writes_over_its_input(clean_ply, tiny_orbit_scene, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    model = out / "cleaned.ply"  # what the scan writes its cleaned model to
    shutil.copy(clean_ply, model)
    before = digest(out)
    refused(
        "never writes over its input", "scan", "--model", model, "--data", tiny_orbit_scene, "--output", out
    )
    assert digest(out) == before
    # the same file under another name, through a hard link
    other = tmp_path / "other"
    other.mkdir()
    os.link(model, other / "cleaned.ply")
    refused("is its input", "scan", "--model", model, "--data", tiny_orbit_scene, "--output", other)
    assert digest(out) == before and digest(other) == {"cleaned.ply": before["cleaned.ply"]}


@pytest.fixture(scope="module")
def linked_scan(tiny_run_pair, tmp_path_factory) -> tuple[Path, Path, dict]:
    """(link, folder, stdout) of a scan of the tiny clean run whose --output is a link to a folder."""
    base = tmp_path_factory.mktemp("linked")
    (base / "real").mkdir()
    (base / "link").symlink_to(base / "real")
    args = ["scan", "--model", str(tiny_run_pair[1]), "--output", str(base / "link")]
    proc = run_cli("stealth-ns", *args, in_process=False)  # the console script of scan, as a user runs it
    return base / "link", base / "real", proc


def test_scan_into_a_linked_output_writes_there_and_records_it(linked_scan, tiny_run_pair, tiny_orbit_scene):
    link, real, proc = linked_scan
    assert "Traceback" not in proc.stderr and "verdict: clean" in proc.stdout
    doc = json.loads((real / "scan.json").read_text())
    assert (real / doc["cleaned"]["run"]).is_file() and not Path(doc["cleaned"]["run"]).is_absolute()
    assert doc["model"]["render_match_above_flat"] >= doc["config"]["render_match_floor"]
    assert 0 < doc["near_depth_share"] <= 1 and f"{doc['near_depth_share']:.2f} of its median" in doc["rule"]
    record = json.loads((real / ".stealth-ns-scan.json").read_text())
    assert record["written_by"] == "stealth-ns scan" and record["folders"] == []
    assert record["files"] == {k: v for k, v in digest(real).items() if k != ".stealth-ns-scan.json"}
    assert {"scan.json", "scan.html", "cleaned.ply"} <= set(record["files"])
    assert any(f.startswith("cleaned/") and f.endswith("config.yml") for f in record["files"])


def test_a_second_scan_replaces_only_its_own_files(linked_scan, tiny_run_pair, tmp_path):
    clean = tiny_run_pair[1]
    out = tmp_path / "out"
    shutil.copytree(linked_scan[1], out)
    record_path = out / ".stealth-ns-scan.json"
    record = json.loads(record_path.read_text())
    # a picture an earlier scan recorded (a view no longer targeted), and the user's own files
    (out / "images" / "frame_99999_full.png").write_bytes(b"stale")
    record["files"]["images/frame_99999_full.png"] = digest(out / "images" / "frame_99999_full.png")[
        "frame_99999_full.png"
    ]
    record_path.write_text(json.dumps(record))
    (out / "notes.txt").write_text("mine")
    (out / "images" / "mine.png").write_bytes(b"mine too")
    # the earlier cleaned run is an input the scan would replace: refused
    cleaned_run = out / json.loads((out / "scan.json").read_text())["cleaned"]["run"]
    before = digest(out)
    refused("holds its input", "scan", "--model", cleaned_run, "--output", out)
    # a file of the scan's that the user changed since: refused
    (out / "scan.html").write_text("my edits")
    refused("scan.html, which stealth-ns did not write there", "scan", "--model", clean, "--output", out)
    assert digest(out) == {**before, "scan.html": digest(out / "scan.html")["scan.html"]}
    (out / "scan.html").unlink()
    stealth_ns("scan", "--model", clean, "--output", out)
    assert not (out / "images" / "frame_99999_full.png").exists()
    assert (out / "notes.txt").read_text() == "mine" and (
        out / "images" / "mine.png"
    ).read_bytes() == b"mine too"
    assert set(json.loads(record_path.read_text())["files"]) == set(record["files"]) - {
        "images/frame_99999_full.png"
    }


# ------------------------------------------------------------------ scan: a model that does not fit
def test_a_model_that_does_not_sit_on_the_cameras_is_refused(clean_ply, tiny_orbit_scene, tmp_path):
    """Moved by a similarity the scan does not know, or put on another scene's cameras, the tiny clean
    model has most of its Gaussians in view and was called clean; now it is refused in one line that
    names every frame tried with its render match, and nothing is written."""
    from scipy.spatial.transform import Rotation

    from stealth_ns.gaussians.ply import read_gaussian_ply, write_gaussian_ply
    from stealth_ns.gaussians.transform import transform_cloud
    from stealth_ns.scene_generator import make_scene

    m = np.eye(4)
    m[:3, :3] = 1.2 * Rotation.random(random_state=1).as_matrix()
    write_gaussian_ply(tmp_path / "moved.ply", transform_cloud(read_gaussian_ply(clean_ply), m))
    make_scene(preset="object", output=tmp_path / "object", resolution="64x64", views=24, seed=0)
    before = {p: digest(p) for p in (tmp_path / "moved.ply", clean_ply, tiny_orbit_scene)}
    for model, data, frames in (
        (tmp_path / "moved.ply", tiny_orbit_scene, ("nerfstudio", "dataset")),
        (clean_ply, tmp_path / "object", ("nerfstudio",)),
    ):
        out = tmp_path / f"scan-{model.stem}"
        message = refused(
            "fits none of the frames tried", "scan", "--model", model, "--data", data, "--output", out
        )
        for frame in frames:
            assert re.search(rf"{frame} \(render match \d+\.\d dB, \d+% of the Gaussians in view\)", message)
        assert re.search(r"the floor is \d+\.\d dB, -?\d+(\.\d+)? dB above a flat image", message)
        assert "docs/design/scan.md" in message and not out.exists()
    assert {p: digest(p) for p in before} == before


def test_a_model_with_broken_rows_is_scanned_without_them(clean_ply, tiny_orbit_scene, tmp_path, capsys):
    """Three broken rows of the tiny clean model (a NaN centre, a zero rotation, an infinite scale; under
    the 1 % left out) are left out: the scan says so in one line and in scan.json, and its cleaned model
    lacks them; the model file and the dataset are left as they were (issue 78)."""
    from stealth_ns.gaussians.ply import read_gaussian_ply, write_gaussian_ply

    cloud = read_gaussian_ply(clean_ply)
    n = len(cloud)
    rows = [0, n // 2, n - 1]
    assert 3 <= 0.01 * n
    cloud.means[rows[0], 0] = np.nan
    cloud.quats[rows[1]] = 0.0
    cloud.log_scales[rows[2], 1] = np.inf
    model = tmp_path / "broken.ply"
    write_gaussian_ply(model, cloud)
    before = {p: digest(p) for p in (model, tiny_orbit_scene)}
    out = tmp_path / "scan"
    capsys.readouterr()
    stealth_ns("scan", "--model", model, "--data", tiny_orbit_scene, "--output", out)
    said = capsys.readouterr().out
    line = f"{model}: left out 3 of {n:,} Gaussians ("
    assert said.count(line) == 1, said
    assert f"; rows {rows[0]}, {rows[1]}, {rows[2]}\n" in said and "3 broken rows left out on reading" in said
    doc = json.loads((out / "scan.json").read_text())
    left = doc["rows_left_out"]
    assert (left["count"], left["total"], left["rows"], left["limit_share"]) == (3, n, rows, 0.01)
    assert left["reasons"] == {"NaN or infinite centre": 1, "NaN or infinite scale": 1, "zero rotation": 1}
    assert "not in the cleaned model" in left["note"] and doc["model"]["gaussians"] == n - 3
    cleaned = read_gaussian_ply(out / "cleaned.ply")
    assert len(cleaned) == n - 3 - doc["removed"] and cleaned.left_out is None
    assert f"3 of {n} rows left out on reading" in (out / "scan.html").read_text()
    assert {p: digest(p) for p in before} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.ply", "scan"]


# ------------------------------------------------------------------ bench scan
def fake_bench(folder: Path, tiny_run_pair, name: str = "results.json") -> Path:
    """A ``bench attack`` results file naming the tiny runs (as bench_runs reads it)."""
    poisoned, clean = tiny_run_pair
    runs = {
        "orbit/clean": {"scene": "orbit", "clean": True, "config": str(clean)},
        "orbit/poisoned": {"scene": "orbit", "clean": False, "config": str(poisoned)},
    }
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(json.dumps({"runs": runs}))
    return folder / name


def test_bench_scan_checks_options_and_results_before_loading(tiny_run_pair, tmp_path):
    bench = fake_bench(tmp_path / "bench", tiny_run_pair).parent
    out = tmp_path / "out"
    refused(
        "--opaque must be in [0, 1), got 2.0",
        "bench",
        "scan",
        "--runs",
        bench,
        "--output",
        out,
        "--opaque",
        "2",
    )
    for text, needle in (
        ('{"runs": {', "is not a `bench attack` results file: not JSON"),
        ("[1, 2]", "has no table of runs"),
        ('{"runs": {"orbit/clean": 3}}', "run 'orbit/clean' is not a run entry"),
        (
            '{"runs": {"orbit/clean": {"scene": "orbit", "config": 7}}}',
            "has a config or metrics that are not",
        ),
    ):
        (tmp_path / "bad").mkdir(exist_ok=True)
        (tmp_path / "bad" / "results.json").write_text(text)
        refused(needle, "bench", "scan", "--runs", tmp_path / "bad", "--output", out)
    refused(
        "--fit-first: no run of scene garden to scan; scenes: orbit",
        "bench", "scan", "--runs", bench, "--output", out, "--fit-first", "garden",
    )  # fmt: skip
    assert not out.exists()
    # before torch and nerfstudio load (the old code scanned the runs, then failed on --opaque)
    argv = ["bench", "scan", "--runs", str(bench), "--output", str(out), "--opaque", "2"]
    code = (
        "import sys\nfrom stealth_ns.cli import main\n"
        "from stealth_ns.foundation.errors import StealthNSError\n"
        f"try:\n    main({argv!r})\nexcept StealthNSError as err:\n"
        "    print(sorted(m for m in ('torch', 'nerfstudio') if m in sys.modules), err)\n"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert loaded.stdout.startswith("[] --opaque must be in"), loaded.stdout + loaded.stderr[-2000:]
    proc = run_cli(
        "stealth-ns", "bench", "scan", "--runs", str(tmp_path / "bad"), "--output", str(out), check=False
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("stealth-ns: error: ")


def test_bench_scan_never_writes_through_a_link_or_over_its_input(tiny_run_pair, tmp_path):
    bench = fake_bench(tmp_path / "bench", tiny_run_pair).parent
    (tmp_path / "precious.md").write_text("the user's notes")
    outside = {p: digest(p) for p in (tmp_path / "precious.md", bench, *(r.parent for r in tiny_run_pair))}
    out = tmp_path / "out"
    out.mkdir()
    (out / "scan.md").symlink_to(tmp_path / "precious.md")
    refused("is a symbolic link", "bench", "scan", "--runs", bench, "--output", out)
    # results named as the bench scan names its own, given inside --output
    inside = fake_bench(tmp_path / "out2", tiny_run_pair, "scan-results.json")
    refused("is its input --runs", "bench", "scan", "--runs", inside, "--output", inside.parent)
    assert {p: digest(p) for p in outside} == outside
    assert digest(inside.parent) == {"scan-results.json": digest(inside)["scan-results.json"]}


def test_bench_scan_records_what_it_wrote(tiny_run_pair, tmp_path):
    bench = fake_bench(tmp_path / "bench", tiny_run_pair).parent
    out = tmp_path / "out"
    stealth_ns("bench", "scan", "--runs", bench, "--output", out, "--only", "orbit/clean")
    rows = json.loads((out / "scan-results.json").read_text())["rows"]
    assert [(r["run"], r["verdict"]) for r in rows] == [("orbit/clean", "clean")]
    record = json.loads((out / ".stealth-ns-bench-scan.json").read_text())
    assert record["files"] == {k: v for k, v in digest(out).items() if not k.startswith(".")}
    assert set(record["files"]) == {"scan-results.json", "scan.md", "roc.png"}
    assert rows[0]["tampered"] == [] and 0 < rows[0]["near_depth_share"] <= 1
    keys = {"view", "index", "share", "gaussians", "pixels", "detailed", "poison"}
    assert rows[0]["groups"] and all(keys == set(g) for g in rows[0]["groups"])
    assert all(g["poison"] == 0.0 for g in rows[0]["groups"])  # the run's tag: a clean run has no poison
    assert "Needs runs of at least two scenes." in (out / "scan.md").read_text()


@pytest.mark.parametrize("frame", ["opensplat-center", "gsplat-normalized"])
def test_bench_scan_as_another_trainers_ply_in_its_default_frame(tiny_run_pair, tmp_path, frame):
    """--as-ply --ply-frame: each run written as OpenSplat (--center) or gsplat (its default) would
    write it, then found in that frame by the scan's frame search."""
    bench = fake_bench(tmp_path / "bench", tiny_run_pair).parent
    out = tmp_path / "out"
    stealth_ns(
        "bench",
        "scan",
        "--runs",
        bench,
        "--output",
        out,
        "--only",
        "orbit/clean",
        "--as-ply",
        "--ply-frame",
        frame,
    )
    (row,) = json.loads((out / "scan-results.json").read_text())["rows"]
    assert (row["run"], row["verdict"], row["frame"]) == ("orbit/clean", "clean", frame)
    assert (out / "plys" / "orbit_clean.ply").is_file()
