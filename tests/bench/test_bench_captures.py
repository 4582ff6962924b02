"""``bench attack --scenes captures``: the phone captures as scenes, their resolution in the tables,
and each run's median step in the runs table."""

from __future__ import annotations

import shutil

import pytest
from dataset_helpers import colmap_folder

from stealth_ns.bench.results import _folder_info
from stealth_ns.bench.scenes import parse_scenes
from stealth_ns.bench.tables import render_markdown
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method_configs.attack_experiments import CAPTURES
from stealth_ns.runs.step_log import STEP_TIME_TAG, median_step_ms


def test_the_captures_group_names_each_capture_and_needs_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StealthNSError, match=r"^scene beer: \.\./shared/data/captures/beer not found$"):
        parse_scenes(["captures"])
    with pytest.raises(StealthNSError, match=r"^scene cup: \.\./shared/data/captures/cup not found$"):
        parse_scenes(["orbit", "cup"])
    with pytest.raises(
        StealthNSError, match=r"unknown scene 'mug'; scenes: .* beer bird cup captures, or NAME"
    ):
        parse_scenes(["mug"])


def test_captures_are_colmap_scenes_with_their_resolution(tiny_orbit_scene, tmp_path, monkeypatch):
    pytest.importorskip("pycolmap")
    work = tmp_path / "work"
    work.mkdir()
    first = colmap_folder(tiny_orbit_scene, work / CAPTURES["beer"])
    for name in ("bird", "cup"):
        shutil.copytree(first, work / CAPTURES[name])
    monkeypatch.chdir(work)
    sources, skipped = parse_scenes(["orbit", "captures"])
    assert [s.name for s in sources] == ["orbit", "beer", "bird", "cup"] and skipped == ()
    assert {s.format for s in sources[1:]} == {"colmap"}
    info = _folder_info(sources[1])
    n_images = len(list((first / "images").iterdir()))
    assert info["views"] == n_images and info["resolution"] == [64, 48]  # the tiny scene's size
    results = {"scenes": {"beer": {"source": "folder", "path": "p", **info}}, "runs": {}, "tables": {}}
    assert f"beer (folder p, 64x48, {n_images} views)" in render_markdown(results)
    # by name, one capture alone
    assert [s.name for s in parse_scenes(["bird"])[0]] == ["bird"]


def test_median_step_is_read_from_the_runs_tensorboard_log(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    assert median_step_ms(tmp_path) is None  # no log
    writer = SummaryWriter(log_dir=str(tmp_path))
    for step, seconds in enumerate([0.5, 0.1, 0.2, 0.3, 9.0]):  # the first and a slow one do not move it
        writer.add_scalar(STEP_TIME_TAG, seconds, step)
    writer.add_scalar("Train Loss", 1.0, 0)
    writer.close()
    assert median_step_ms(tmp_path) == 300.0


def test_the_runs_table_names_each_runs_median_step():
    runs = {
        "cup/clean": {"label": "clean", "clean": True, "train_seconds": 300.0, "median_step_ms": 95.04,
                      "status": "trained"},
        "cup/easy": {"label": "Easy", "clean": False, "status": "failed"},
    }  # fmt: skip
    text = render_markdown({"scenes": {}, "runs": runs, "tables": {}})
    assert "| cup/clean | clean | – | – | – | – | – | – | 5.0 min | 95 ms | trained |" in text
    assert "| cup/easy | Easy |" in text and text.rstrip().endswith("n/a | n/a | failed |")
