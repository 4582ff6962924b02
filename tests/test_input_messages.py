"""Input that nerfstudio or the attack meets without a useful word (issue 57, class 7): a COLMAP folder
read at nerfstudio's default ``--colmap-path`` (colmap/sparse/0) or with nerfstudio-data is told where
its model is and which flag reads it; ``stealth-ns ipa-poison --every N`` not below ``--iterations``
is refused instead of poisoning with an untrained model."""

from __future__ import annotations

from pathlib import Path

import pytest

from stealth_ns.cli import main
from stealth_ns.datasets.check import check_colmap, check_dataset
from stealth_ns.datasets.source import colmap_models
from stealth_ns.foundation.errors import StealthNSError


def _colmap_folder(root: Path, *models: str) -> Path:
    """A folder with ``images/`` and a (placeholder) COLMAP model in each of ``models``: where a model is
    is decided by its files' names, before anything is read."""
    (root / "images").mkdir(parents=True)
    for model in models:
        (root / model).mkdir(parents=True)
        for name in ("cameras", "images", "points3D"):
            (root / model / f"{name}.bin").write_bytes(b"")
    return root


def _start_up(dataparser) -> str:
    """The one line ns-train's start-up check stops with for ``dataparser``."""
    from stealth_ns.method.datamanager import StealthDataManagerConfig, check_nerfstudio_data

    with pytest.raises(SystemExit) as exc:
        check_nerfstudio_data(StealthDataManagerConfig(dataparser=dataparser))
    message = str(exc.value)
    assert message.startswith("stealth-ns: error: ") and "\n" not in message, message
    return message


def test_colmap_at_nerfstudios_default_path_says_where_the_model_is(tmp_path):
    """Before: "the COLMAP model DATA/colmap/sparse/0 has no points3D", a folder that does not exist."""
    from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig

    data = _colmap_folder(tmp_path / "capture", "sparse/0")
    message = _start_up(ColmapDataParserConfig(data=data))
    assert f"{data / 'colmap/sparse/0'} (nerfstudio's default --colmap-path) holds no COLMAP model" in message
    assert message.endswith(f"the model of {data} is in sparse/0; give --colmap-path sparse/0"), message
    with pytest.raises(StealthNSError, match=r"is in sparse/0; give --colmap-path sparse/0"):
        check_colmap(data, "sparse/1")


def test_a_model_elsewhere_in_the_folder_is_found(tmp_path):
    data = _colmap_folder(tmp_path / "capture", "reconstruction/sparse/1", "sparse/0", ".hidden/sparse/0")
    (data / "images" / "sparse").mkdir()  # a folder with no model on the way
    assert colmap_models(data) == ["sparse/0", "reconstruction/sparse/1"]
    with pytest.raises(StealthNSError, match=r"is in sparse/0 \(others: reconstruction/sparse/1\)"):
        check_colmap(data, "colmap/sparse/0")


def test_a_folder_without_a_model_says_so(tmp_path):
    data = _colmap_folder(tmp_path / "capture")
    with pytest.raises(StealthNSError, match=r"holds no COLMAP model .*, nor does any folder in .*capture"):
        check_colmap(data, "colmap/sparse/0")
    with pytest.raises(StealthNSError, match=r"dataset folder .*missing does not exist"):
        check_colmap(tmp_path / "missing", "colmap/sparse/0")


def test_nerfstudio_data_on_a_colmap_folder_names_the_colmap_dataparser(tmp_path, capsys):
    """Before: the check passed (it read the folder as COLMAP) and nerfstudio-data's parser raised
    FileNotFoundError on transforms.json."""
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    data = _colmap_folder(tmp_path / "capture", "sparse/0")
    message = _start_up(NerfstudioDataParserConfig(data=data))
    assert message == (
        f"stealth-ns: error: {data / 'transforms.json'} does not exist: {data} is a COLMAP dataset; train it "
        f"with `colmap --data {data} --colmap-path sparse/0` in place of nerfstudio-data"
    )
    with pytest.raises(StealthNSError, match="is a COLMAP dataset"):
        check_dataset(data, dataparser="nerfstudio-data")


# ---------------------------------------------------------------------------------- ipa-poison --every
def test_attack_epochs_run_at_every_multiple_of_every():
    from stealth_ns.poisoned_datasets.ipa import attack_epoch_steps, check_epochs

    assert attack_epoch_steps(10, 20) == [0, 10]
    assert attack_epoch_steps(200, 3000)[-1] == 2800
    assert attack_epoch_steps(50, 20) == [0]
    check_epochs(10, 20)
    check_epochs(19, 20)
    for every, iterations in ((20, 20), (50, 20), (1, 1)):
        with pytest.raises(StealthNSError, match=f"--every {every} is not below --iterations {iterations}"):
            check_epochs(every, iterations)


def test_ipa_poison_refuses_every_beyond_the_training_before_writing(tiny_orbit_scene, tmp_path):
    """Before: one attack epoch after step 0, on the untrained model, written as the poisoned copy."""
    out = tmp_path / "poisoned"
    args = ["--data", str(tiny_orbit_scene), "--output", str(out), "--every", "50", "--iterations", "20"]
    with pytest.raises(StealthNSError) as err:  # the entry point prints it as one line and exits 2
        main(["ipa-poison", *args])
    message = str(err.value)
    assert (
        message.startswith("--every 50 is not below --iterations 20: the only attack epoch")
        and "\n" not in message
    )
    assert not out.exists()
