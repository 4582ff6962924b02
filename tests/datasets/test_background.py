"""RGB images on a uniform white or black background, trained under the random one: ns-train says so
(issue 32, class 6)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from stealth_ns.attack.config import AttackConfig
from stealth_ns.datasets.background import uniform_background
from stealth_ns.images.io import read_image, save_image
from stealth_ns.poisoned_datasets.dataset_copy import open_source
from stealth_ns.poisoned_datasets.setup import setup_trainer, trainer_config


def _framed(colour: int, border: int = 4, shape: tuple[int, int] = (24, 32)) -> np.ndarray:
    image = np.random.default_rng(0).integers(40, 200, (*shape, 3)).astype(np.uint8)
    image[:border], image[-border:], image[:, :border], image[:, -border:] = colour, colour, colour, colour
    return image


def test_uniform_backgrounds_are_told_apart():
    assert uniform_background([_framed(255)] * 5) == ("white", 1.0)
    assert uniform_background([_framed(0)] * 4 + [_framed(128)]) == ("black", 0.8)
    assert uniform_background([_framed(253)] * 3) == ("white", 1.0)  # within the tolerance (JPEG)
    assert uniform_background([_framed(255)] * 3 + [_framed(128)] * 2) is None  # 60 %: not the dataset
    assert uniform_background([_framed(245)] * 3) is None  # light grey is not white
    rgba = np.dstack([_framed(255), np.full((24, 32), 255, np.uint8)])
    assert uniform_background([rgba] * 3) is None  # the model composites transparent images itself
    assert uniform_background([]) is None


def _trainer_output(scene: Path, out: Path, capsys, background: str) -> str:
    config = trainer_config(open_source(scene), AttackConfig(enabled=False))
    config.output_dir = out
    config.timestamp = f"{scene.name}-{background}"  # a run folder of its own (one training per folder)
    config.pipeline.model.background_color = background
    setup_trainer(config)
    return capsys.readouterr().out


def test_ns_train_says_so_at_start_up(tiny_orbit_scene, tmp_path, capsys):
    scene = Path(shutil.copytree(tiny_orbit_scene, tmp_path / "white"))
    for png in (scene / "images").glob("*.png"):
        image = read_image(png, "image")
        image[:5], image[-5:], image[:, :5], image[:, -5:] = 255, 255, 255, 255
        save_image(png, image)
    said = _trainer_output(scene, tmp_path / "runs", capsys, "random")
    assert "uniform white background (100% of 8 looked at)" in said
    assert "--pipeline.model.background-color white" in said
    assert "uniform" not in _trainer_output(scene, tmp_path / "runs", capsys, "white")
    assert "uniform" not in _trainer_output(tiny_orbit_scene, tmp_path / "runs", capsys, "random")
