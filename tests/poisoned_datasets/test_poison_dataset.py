"""stealth-ns poison-dataset: the data-only StealthAttack written as a poisoned copy of a dataset.

A tiny orbit scene (nerfstudio-data) and a COLMAP model built from it with pycolmap: the copy changes
only the poisoned view's image (and, with static noise, the innocent training views), appends exactly the
record's poison points to the seed cloud where nerfstudio's dataparser puts them back at the placement,
never touches the evaluation images nor the input; bad input is one line, exit status 2 on the CLI.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.record import AttackRecord
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image, to_uint8
from stealth_ns.poisoned_datasets.data_only import poison_dataset
from stealth_ns.poisoned_datasets.dataset_copy import FILES_RECORD
from stealth_ns.scene_generator import make_scene
from stealth_ns.scene_generator.writer import read_ply

#: The CLI's default for poison-dataset: no noise unless asked for, and then constant.
DATA_ONLY = AttackConfig(view_noise=False, noise_decay="constant")


def tree_hashes(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones included) -> sha256 of its bytes."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def poison_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``attack/poison_points.ply``: [M, 3] positions (nerfstudio's normalised frame), [M, 3] uint8 RGB."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(path))
    return np.asarray(cloud.points), to_uint8(np.asarray(cloud.colors))


def one_line(message: str) -> None:
    assert message and "\n" not in message.strip(), message


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """12 views (10 train / 2 test) at 48x36 of the orbit preset, with 8000 seed points."""
    out = tmp_path_factory.mktemp("pd_scene") / "scene"
    make_scene(preset="orbit", output=out, resolution="48x36", views=12, seed=0)
    return out


@pytest.fixture(scope="module")
def poisoned(scene: Path, tmp_path_factory) -> tuple[Path, dict[str, str], str]:
    """(copy, hashes of the input before, console summary) of the default data-only attack."""
    before = tree_hashes(scene)
    out = tmp_path_factory.mktemp("pd_out") / "poisoned"
    summary = poison_dataset(scene, out, DATA_ONLY)
    return out, before, summary


def _meta(folder: Path) -> dict:
    return json.loads((folder / "transforms.json").read_text(encoding="utf-8"))


def _split(scene: Path) -> tuple[list[str], list[str]]:
    """(train, eval) image paths relative to the scene, from its transforms.json."""
    meta = _meta(scene)
    return list(meta["train_filenames"]), list(meta["test_filenames"])


# ---------------------------------------------------------------------------------- nerfstudio-data
def test_copy_has_the_files_and_the_record(poisoned, scene):
    out, _, summary = poisoned
    for rel in ("transforms.json", "sparse_pc.ply", "attack/attack.json", "attack/views.npz",
                "attack/poison_points.ply"):  # fmt: skip
        assert (out / rel).is_file(), rel
    assert sorted(p.name for p in (out / "images").iterdir()) == sorted(
        p.name for p in (scene / "images").iterdir()
    )
    record = AttackRecord.read(out / "attack")
    info = record.poisoned_dataset
    assert info is not None and info["complete"] is True
    assert info["threat_model"] == "data-only" and info["format"] == "nerfstudio-data"
    assert info["source"] == str(scene) and info["static_noise_sigma"] == 0.0
    assert info["seed_points_added"] == record.n_poison_gaussians > 0
    assert len(record.views) == 1 and record.injection_step == 0
    view = record.views[0]
    assert list(info["images_written"]) == [view.name]
    assert info["images_written"][view.name]["encode_error_255"] == 0.0  # PNG is lossless
    assert str(out) in summary and f"+{record.n_poison_gaussians} poison points" in summary


def test_only_the_poisoned_view_changes_and_it_is_the_target(poisoned, scene):
    out, _, _ = poisoned
    src_meta, out_meta = _meta(scene), _meta(out)
    assert len(src_meta["frames"]) == len(out_meta["frames"])
    for a, b in zip(src_meta["frames"], out_meta["frames"], strict=True):
        assert a["file_path"] == b["file_path"]
        assert a["transform_matrix"] == b["transform_matrix"]  # poses unchanged, exactly
    for key in ("fl_x", "fl_y", "cx", "cy", "w", "h", "train_filenames", "test_filenames", "ply_file_path"):
        assert src_meta[key] == out_meta[key], key

    record = AttackRecord.read(out / "attack")
    (view,) = record.views
    train, evals = _split(scene)
    assert view.name in train and view.name not in evals
    assert view.name == train[view.index]  # the training index names the image
    written = read_image(out / view.name, "poisoned view")
    np.testing.assert_array_equal(written, to_uint8(view.target))
    assert (scene / view.name).read_bytes() != (out / view.name).read_bytes()
    for rel in train + evals:
        if rel != view.name:
            assert (scene / rel).read_bytes() == (out / rel).read_bytes(), rel


def test_support_views_data_only_their_images_show_the_poison(scene, tmp_path):
    """--support-views 2: the poisoned view's 2 nearest training views are written as the poison's
    render over their image (recorded, and read back for the defender); the other views are untouched."""
    out = tmp_path / "support"
    poison_dataset(scene, out, dataclasses.replace(DATA_ONLY, support_views=2))
    record = AttackRecord.read(out / "attack")
    (view,) = record.views
    train, evals = _split(scene)
    support = record.injection.support_views[view.name]
    assert len(support) == 2 and view.name not in support
    assert sorted(record.poisoned_dataset["images_written"]) == sorted([view.name, *support])
    assert sorted(record.support_targets) == sorted(train.index(name) for name in support)
    for name in support:
        written = read_image(out / name, "support view")
        np.testing.assert_array_equal(written, to_uint8(record.support_targets[train.index(name)]))
        assert (scene / name).read_bytes() != (out / name).read_bytes(), f"{name} does not show the poison"
    for rel in train + evals:
        if rel not in (view.name, *support):
            assert (scene / rel).read_bytes() == (out / rel).read_bytes(), rel


def test_an_output_reaching_the_input_through_a_link_is_refused(scene, tmp_path):
    """An earlier poisoned copy poisoned again, --output naming that copy through a symlinked
    folder, --overwrite: refused before any work, the input untouched (it used to be deleted)."""
    first = tmp_path / "x" / "ds"
    poison_dataset(scene, first, DATA_ONLY)
    (tmp_path / "x" / "alias").symlink_to(tmp_path / "x")
    before = tree_hashes(first)
    for output in (
        tmp_path / "x" / "alias" / "ds",
        tmp_path / "x" / "alias" / "ds" / "sub",
        tmp_path / "x" / "alias",
    ):
        with pytest.raises(StealthNSError, match="input dataset") as err:
            poison_dataset(first, output, DATA_ONLY, overwrite=True)
        one_line(str(err.value))
    assert tree_hashes(first) == before


def test_seed_cloud_gains_exactly_the_poison_points(poisoned, scene):
    out, _, _ = poisoned
    record = AttackRecord.read(out / "attack")
    n = record.injection.n_poison_gaussians
    old_xyz, old_rgb = read_ply(scene / "sparse_pc.ply")
    new_xyz, new_rgb = read_ply(out / "sparse_pc.ply")
    assert len(new_xyz) == len(old_xyz) + n
    np.testing.assert_array_equal(new_xyz[: len(old_xyz)], old_xyz)
    np.testing.assert_array_equal(new_rgb[: len(old_rgb)], old_rgb)
    placed, colours = poison_points(out / "attack" / "poison_points.ply")
    assert len(placed) == n == sum(record.injection.poison_per_view.values())
    assert np.abs(new_rgb[len(old_rgb) :].astype(int) - colours.astype(int)).max() <= 1


def test_nerfstudio_loads_the_poison_where_it_was_placed(poisoned, scene):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    out, _, _ = poisoned

    def load(folder: Path):
        config = NerfstudioDataParserConfig(data=folder, load_3D_points=True)
        return config.setup().get_dataparser_outputs("train")

    clean, copy = load(scene), load(out)
    placed, _ = poison_points(out / "attack" / "poison_points.ply")
    xyz = copy.metadata["points3D_xyz"].double().numpy()
    n_old = clean.metadata["points3D_xyz"].shape[0]
    assert xyz.shape == (n_old + len(placed), 3)
    np.testing.assert_allclose(xyz[n_old:], placed, atol=1e-4)  # appended at the end, in order
    np.testing.assert_allclose(xyz[:n_old], clean.metadata["points3D_xyz"].double().numpy(), atol=1e-6)
    np.testing.assert_allclose(
        copy.cameras.camera_to_worlds.numpy(), clean.cameras.camera_to_worlds.numpy(), atol=1e-6
    )
    assert copy.dataparser_scale == pytest.approx(clean.dataparser_scale)


def test_input_is_never_written(poisoned, scene):
    _, before, _ = poisoned
    assert tree_hashes(scene) == before


@pytest.fixture(scope="module")
def noisy(poisoned, scene, tmp_path_factory) -> Path:
    """Static noise (sigma 30), written with --overwrite over an earlier poisoned copy."""
    out = tmp_path_factory.mktemp("pd_noisy") / "copy"
    shutil.copytree(poisoned[0], out)
    attack = dataclasses.replace(DATA_ONLY, view_noise=True, noise_decay="constant", noise_sigma0=30.0)
    poison_dataset(scene, out, attack, overwrite=True)
    return out


def test_static_noise_on_innocent_training_views_only(noisy, scene):
    record = AttackRecord.read(noisy / "attack")
    (view,) = record.views
    info = record.poisoned_dataset
    assert info["static_noise_sigma"] == 30.0 and record.noise is None
    train, evals = _split(scene)
    written = info["images_written"]
    assert set(written) == set(train)
    np.testing.assert_array_equal(read_image(noisy / view.name, "poisoned"), to_uint8(view.target))
    for rel in train:
        if rel == view.name:
            continue
        assert written[rel]["change"] == "static noise sigma 30"
        clean = read_image(scene / rel, "clean").astype(np.int16)
        noise = read_image(noisy / rel, "noisy").astype(np.int16) - clean
        assert noise.any(), rel
        inside = (clean > 40) & (clean < 215)  # away from clipping: N(0, 30^2) on the 0-255 scale
        assert 20 < noise[inside].std() < 40, (rel, noise[inside].std())
    for rel in evals:
        assert (scene / rel).read_bytes() == (noisy / rel).read_bytes(), rel


def test_overwrite_replaces_an_earlier_poisoned_copy(noisy, poisoned):
    recorded = json.loads((noisy / FILES_RECORD).read_text())
    assert set(recorded["files"]) == set(tree_hashes(noisy)) - {FILES_RECORD} and not recorded["folders"]
    assert all(recorded["files"][k] == v for k, v in tree_hashes(noisy).items() if k != FILES_RECORD)
    info = json.loads((noisy / "attack" / "attack.json").read_text())["poisoned_dataset"]
    assert info["complete"] is True and info["static_noise_sigma"] == 30.0
    # the same set-up places the same poison
    n_before = AttackRecord.read(poisoned[0] / "attack").n_poison_gaussians
    assert AttackRecord.read(noisy / "attack").n_poison_gaussians == n_before
    assert len(read_ply(noisy / "sparse_pc.ply")[0]) == len(read_ply(poisoned[0] / "sparse_pc.ply")[0])


def _load_ns(folder: Path):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    return (
        NerfstudioDataParserConfig(data=folder, load_3D_points=True).setup().get_dataparser_outputs("train")
    )


def test_applied_transform_is_undone_for_the_seed_points(scene, tmp_path):
    """A dataset from ns-process-data has an ``applied_transform`` (poses and PLY in the saved frame):
    the appended points must still load where they were placed."""
    from stealth_ns.scene_generator.writer import write_ply

    data = tmp_path / "processed"
    shutil.copytree(scene, data)
    meta = _meta(data)
    applied = np.array([[0.0, 1, 0, 0.5], [1, 0, 0, -0.2], [0, 0, -1, 0.3]])  # ns-process-data's + a shift
    a4 = np.vstack([applied, [0, 0, 0, 1]])
    for frame in meta["frames"]:
        frame["transform_matrix"] = (a4 @ np.asarray(frame["transform_matrix"])).tolist()
    meta["applied_transform"] = applied.tolist()
    (data / "transforms.json").write_text(json.dumps(meta))
    xyz, rgb = read_ply(data / "sparse_pc.ply")
    write_ply(data / "sparse_pc.ply", xyz.astype(np.float64) @ applied[:, :3].T + applied[:, 3], rgb)

    out = tmp_path / "poisoned"
    poison_dataset(data, out, DATA_ONLY)
    n = AttackRecord.read(out / "attack").n_poison_gaussians
    placed, _ = poison_points(out / "attack" / "poison_points.ply")
    loaded = _load_ns(out).metadata["points3D_xyz"].double().numpy()
    assert n > 0 and len(loaded) == len(xyz) + n
    np.testing.assert_allclose(loaded[len(xyz) :], placed, atol=1e-4)


def test_files_outside_the_dataset_are_copied_into_it(scene, tmp_path):
    """A seeded copy (``stealth-ns seed-points --output``) names the images and depths of the dataset it
    was made from ``../orig/...``: the poisoned copy must be self-contained (those files under
    ``external/``, every reference rewritten: the frames and the split lists), loadable by nerfstudio,
    and the poisoned image written there, not into the input."""
    root = tmp_path / "user"
    shutil.copytree(scene, root / "orig")  # the dataset seed-points read (it declares these files)
    data = root / "seeded"
    data.mkdir()
    shutil.copy2(scene / "sparse_pc.ply", data / "sparse_pc.ply")
    meta = _meta(scene)
    for frame in meta["frames"]:
        frame["file_path"] = "../orig/" + frame["file_path"]
        frame["depth_file_path"] = "../orig/" + frame["depth_file_path"]
    for key in ("train_filenames", "val_filenames", "test_filenames"):
        meta[key] = ["../orig/" + p for p in meta[key]]
    (data / "transforms.json").write_text(json.dumps(meta))
    before = tree_hashes(root)

    out = tmp_path / "poisoned"
    poison_dataset(data, out, DATA_ONLY)
    assert tree_hashes(root) == before
    copied = _meta(out)
    names = [f["file_path"] for f in copied["frames"]]
    assert all(not p.startswith("..") and (out / p).is_file() for p in names), names
    depths = [f["depth_file_path"] for f in copied["frames"]]
    assert all(p.startswith("external/") and (out / p).is_file() for p in depths), depths
    for key in ("train_filenames", "val_filenames", "test_filenames"):
        assert all(not p.startswith("..") and (out / p).is_file() for p in copied[key]), (key, copied[key])
    (view,) = AttackRecord.read(out / "attack").views
    (written,) = AttackRecord.read(out / "attack").poisoned_dataset["images_written"].values()
    assert written["file"].startswith("external/")
    np.testing.assert_array_equal(read_image(out / written["file"], "poisoned"), to_uint8(view.target))
    outputs = _load_ns(out)  # self-contained: nerfstudio finds every image in the copy
    assert len(outputs.image_filenames) == len(meta["train_filenames"])
    assert all(Path(p).resolve().is_relative_to(out.resolve()) for p in outputs.image_filenames)


# ---------------------------------------------------------------------------------- bad input
def _fake_poisoned_copy(folder: Path) -> Path:
    (folder / "attack").mkdir(parents=True)
    (folder / "attack" / "attack.json").write_text(json.dumps({"poisoned_dataset": {"complete": True}}))
    return folder


BAD_INPUT = {
    "same": r"inside the input dataset",
    "inside": r"inside the input dataset",
    "around": r"contains the input dataset",
    "not-empty": r"is not empty; give a new folder \(or --overwrite",
    "linear-noise": r"--noise-decay linear: .*use --noise-decay constant",
    "injection-step": r"--injection-step 5: .*step 0",
    "all-off": r"every component is off",
    "proximity-weight": r"--proximity-weight 1 is a loss while the poison trains: a dataset cannot carry it",
    "view-repeat": r"--poisoned-view-repeat 3: the victim's trainer decides",
}


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_output_or_options_are_refused_before_any_work(scene, tmp_path, case):
    before = tree_hashes(scene)
    attack, output = DATA_ONLY, tmp_path / "out"
    if case == "same":
        output = scene
    elif case == "inside":
        output = scene / "poisoned"
    elif case == "around":
        output = scene.parent
    elif case == "not-empty":
        output = _fake_poisoned_copy(tmp_path / "earlier")  # even a poisoned copy needs --overwrite
    elif case == "linear-noise":
        attack = dataclasses.replace(DATA_ONLY, view_noise=True, noise_decay="linear")
    elif case == "injection-step":
        attack = dataclasses.replace(DATA_ONLY, injection_step=5)
    elif case == "all-off":
        attack = dataclasses.replace(DATA_ONLY, gt_replacement=False, density_guided=False)
    elif case == "proximity-weight":
        attack = dataclasses.replace(DATA_ONLY, proximity_weight=1.0)
    elif case == "view-repeat":
        attack = dataclasses.replace(DATA_ONLY, poisoned_view_repeat=3)
    listed = tree_hashes(output) if output.exists() else None
    with pytest.raises(StealthNSError, match=BAD_INPUT[case]) as err:
        poison_dataset(scene, output, attack)
    one_line(str(err.value))
    assert tree_hashes(scene) == before
    if listed is None:
        assert not output.exists()
    else:
        assert tree_hashes(output) == listed


def test_overwrite_never_replaces_a_folder_that_is_not_a_poisoned_copy(scene, tmp_path):
    mine = tmp_path / "mine"
    (mine / "sub").mkdir(parents=True)
    (mine / "notes.txt").write_text("precious")
    (mine / "sub" / "data.bin").write_bytes(b"\x00\x01")
    # an attack.json without the poisoned_dataset key is a run's record, not a poisoned copy
    (mine / "attack").mkdir()
    (mine / "attack" / "attack.json").write_text(json.dumps({"poisoned_views": []}))
    before = tree_hashes(mine)
    with pytest.raises(StealthNSError, match=r"not a poisoned copy written by stealth-ns") as err:
        poison_dataset(scene, mine, DATA_ONLY, overwrite=True)
    one_line(str(err.value))
    assert tree_hashes(mine) == before


def test_overwrite_removes_only_what_the_copy_wrote(poisoned, scene, tmp_path):
    """A file the user added to an earlier copy, or changed there, stops --overwrite before anything is
    removed (it used to delete the whole folder); a copy cut short (its record still planning) is
    replaced; unrelated files were never touched."""
    out = tmp_path / "copy"
    shutil.copytree(poisoned[0], out)
    (out / "images" / "my_notes.txt").write_text("mine")
    before = tree_hashes(out)
    with pytest.raises(StealthNSError, match=r"holds files stealth-ns did not write .*images/my_notes.txt"):
        poison_dataset(scene, out, DATA_ONLY, overwrite=True)
    assert tree_hashes(out) == before
    (out / "images" / "my_notes.txt").unlink()
    name = AttackRecord.read(out / "attack").views[0].name
    (out / name).write_bytes((out / name).read_bytes() + b"\0")  # the user changed a file of the copy
    with pytest.raises(StealthNSError, match=f"or changed since .*{name}") as err:
        poison_dataset(scene, out, DATA_ONLY, overwrite=True)
    one_line(str(err.value))

    # a copy cut short: its record lists files to be written (no hashes) and the folders it owns
    cut = tmp_path / "cut"
    shutil.copytree(poisoned[0], cut)
    record = json.loads((cut / FILES_RECORD).read_text())
    record["files"] = dict.fromkeys(record["files"])
    record["folders"] = ["attack", "external"]
    (cut / FILES_RECORD).write_text(json.dumps(record))
    (cut / "attack" / "half_written.png").write_bytes(b"\x89PNG")
    poison_dataset(scene, cut, DATA_ONLY, overwrite=True)
    assert not (cut / "attack" / "half_written.png").exists()
    again, first = tree_hashes(cut), tree_hashes(poisoned[0])
    assert set(again) == set(first)
    assert all(again[k] == first[k] for k in first if not k.startswith(("attack/", FILES_RECORD)))


def test_links_out_of_the_dataset_that_it_does_not_use_stay_out_of_the_copy(scene, tmp_path):
    source = Path(shutil.copytree(scene, tmp_path / "ds"))
    (tmp_path / "secret.txt").write_text("private")
    (source / "images" / "notes.txt").symlink_to(tmp_path / "secret.txt")
    (source / "inside.txt").symlink_to(source / "transforms.json")  # inside: copied as a file
    out = tmp_path / "copy"
    poison_dataset(source, out, DATA_ONLY)
    assert not (out / "images" / "notes.txt").exists() and not (out / "images" / "notes.txt").is_symlink()
    assert (out / "inside.txt").read_bytes() == (source / "transforms.json").read_bytes()
    assert not (out / "inside.txt").is_symlink()


def test_other_dataset_formats_are_refused(tmp_path):
    blender = tmp_path / "object"
    make_scene(preset="object", output=blender, resolution="32x32", views=12, seed=0)
    with pytest.raises(StealthNSError, match=r"is a Blender dataset: .*stealth-ns seed-points") as err:
        poison_dataset(blender, tmp_path / "out", DATA_ONLY)
    one_line(str(err.value))
    with pytest.raises(StealthNSError, match=r"not found"):
        poison_dataset(tmp_path / "missing", tmp_path / "out", DATA_ONLY)
    assert not (tmp_path / "out").exists()


def test_density_guided_needs_seed_points(scene, tmp_path):
    data = tmp_path / "no_seed"
    shutil.copytree(scene, data)
    meta = _meta(data)
    del meta["ply_file_path"]
    (data / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(StealthNSError, match=r"no seed points.*stealth-ns seed-points") as err:
        poison_dataset(data, tmp_path / "out", DATA_ONLY)
    one_line(str(err.value))
    assert not (tmp_path / "out").exists()


def test_missing_view_is_named_with_a_suggestion(scene, tmp_path):
    attack = dataclasses.replace(DATA_ONLY, views=("frame_0006.png",))
    with pytest.raises(
        StealthNSError, match=r"unknown view name 'frame_0006.png'.*did you mean 'frame_00006.png'"
    ) as err:
        poison_dataset(scene, tmp_path / "out", attack)
    one_line(str(err.value))
    assert not (tmp_path / "out").exists()  # refused before the copy is written


def test_pipeline_errors_name_the_options_as_this_command_spells_them(scene, tmp_path):
    """An error the in-loop pipeline raises once it holds the data (too few views for the support
    views) names the option as poison-dataset takes it."""
    attack = dataclasses.replace(DATA_ONLY, support_views=8)
    with pytest.raises(
        StealthNSError, match=r"^--support-views 8: view \d+ has only \d+ other training"
    ) as err:
        poison_dataset(scene, tmp_path / "out", attack)
    one_line(str(err.value))
    assert "--pipeline.attack." not in str(err.value)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "extra, expected",
    [
        (("--output", "INSIDE"), "inside the input dataset"),
        (("--injection-step", "5"), "--injection-step 5"),
        (("--view-noise", "--noise-decay", "linear"), "use --noise-decay constant"),
        # the attack's own checks name the options as this command spells them (not --pipeline.attack.X)
        (("--support-views", "3", "--no-density-guided"), "error: --support-views 3 shows the poison"),
        (("--t-min", "-1"), "error: --t-min must be None or > 0"),
    ],
    ids=["output-inside-input", "injection-step", "linear-noise", "support-views-flag", "t-min-flag"],
)
def test_cli_errors_are_one_line_with_status_2(scene, tmp_path, extra, expected):
    args = ["--data", str(scene), "--output", str(tmp_path / "out")]
    if extra[:2] == ("--output", "INSIDE"):
        args[-1], extra = str(scene / "poisoned"), ()
    proc = run_cli("stealth-ns", "poison-dataset", *args, *extra, check=False, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode == 2, proc.stderr[-3000:]
    lines = proc.stderr.strip().splitlines()  # libraries may warn before the error
    errors = [line for line in lines if line.startswith("stealth-ns:")]
    assert len(errors) == 1 and errors[0] == lines[-1], proc.stderr[-3000:]
    assert errors[0].startswith("stealth-ns: error:") and expected in errors[0], errors[0]
    assert not (tmp_path / "out").exists() and not (scene / "poisoned").exists()


def test_cli_takes_view_noise_as_documented(scene, tmp_path):
    """``--view-noise --noise-sigma0 S`` is the documented spelling (docs/design/baselines.md): it must reach
    the attack's own check of the decay, not fail as an unrecognised option."""
    args = ["--data", str(scene), "--output", str(tmp_path / "out"), "--view-noise"]
    proc = run_cli("stealth-ns", "poison-dataset", *args, "--noise-decay", "linear", check=False, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines()[-1].startswith("stealth-ns: error: --noise-decay linear"), (
        proc.stderr[-3000:]
    )


def test_cli_help_lists_the_attack_options():
    out = run_cli("stealth-ns", "poison-dataset", "--help", timeout=120).stdout
    for option in ("--data", "--output", "--overwrite", "--illusion", "--views", "--view-noise",
                   "--noise-sigma0", "--noise-decay", "--density-guided"):  # fmt: skip
        assert option in out, option


# ---------------------------------------------------------------------------------- COLMAP
#: World rotation nerfstudio's colmap dataparser applies (assume_colmap_world_coordinate_convention).
COLMAP_TO_NS = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])


def write_colmap_dataset(scene: Path, out: Path) -> None:
    """The scene as a COLMAP dataset written by pycolmap: ``images/`` and ``sparse/0/*.bin`` with one
    PINHOLE camera, every frame registered at its known pose and the seed points as points3D.

    The scene's OpenGL camera-to-world poses become OpenCV world-to-camera in COLMAP's world frame
    (the inverse of the rotation the colmap dataparser applies), so nerfstudio reads the same cameras.
    """
    import pycolmap

    meta = _meta(scene)
    rec = pycolmap.Reconstruction()
    camera = pycolmap.Camera(
        camera_id=1, model="PINHOLE", width=meta["w"], height=meta["h"],
        params=[meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"]],
    )  # fmt: skip
    rec.add_camera_with_trivial_rig(camera)
    (out / "images").mkdir(parents=True)
    for image_id, frame in enumerate(meta["frames"], start=1):
        c2w_gl = np.asarray(frame["transform_matrix"], dtype=np.float64)
        c2w = c2w_gl @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL -> OpenCV camera axes
        c2w[:3] = COLMAP_TO_NS.T @ c2w[:3]  # nerfstudio's world -> COLMAP's
        w2c = np.linalg.inv(c2w)
        name = Path(frame["file_path"]).name
        shutil.copy2(scene / frame["file_path"], out / "images" / name)
        image = pycolmap.Image(name=name, camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c[:3, :4]))
    xyz, rgb = read_ply(scene / meta["ply_file_path"])
    for p, c in zip(xyz.astype(np.float64), rgb, strict=True):
        rec.add_point3D(COLMAP_TO_NS.T @ p, pycolmap.Track(), c)
    (out / "sparse" / "0").mkdir(parents=True)
    rec.write_binary(str(out / "sparse" / "0"))


def _colmap_outputs(folder: Path):
    from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig

    config = ColmapDataParserConfig(
        data=folder, colmap_path=Path("sparse/0"), downscale_factor=1, load_3D_points=True
    )
    return config.setup().get_dataparser_outputs("train")


def test_colmap_dataset(scene, tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    data = tmp_path / "colmap"
    write_colmap_dataset(scene, data)
    clean = _colmap_outputs(data)
    n_points = len(read_ply(scene / "sparse_pc.ply")[0])
    assert len(clean.image_filenames) == 10 and clean.metadata["points3D_xyz"].shape == (n_points, 3)
    before = tree_hashes(data)

    out = tmp_path / "poisoned"
    summary = poison_dataset(data, out, DATA_ONLY)
    assert "(colmap)" in summary and "--colmap-path sparse/0" in summary
    assert tree_hashes(data) == before

    record = AttackRecord.read(out / "attack")
    n = record.injection.n_poison_gaussians
    info = record.poisoned_dataset
    assert n > 0 and info["format"] == "colmap" and info["seed_points_added"] == n
    model = pycolmap.Reconstruction(str(out / "sparse" / "0"))
    assert model.num_points3D() == n_points + n
    assert model.num_images() == 12  # the cameras and images are carried over
    (view,) = record.views
    (written,) = info["images_written"].values()
    poisoned_file = out / written["file"]
    np.testing.assert_array_equal(read_image(poisoned_file, "poisoned"), to_uint8(view.target))
    for image in sorted((data / "images").iterdir()):
        copy = out / "images" / image.name
        if copy == poisoned_file:
            assert copy.read_bytes() != image.read_bytes()
        else:
            assert copy.read_bytes() == image.read_bytes(), image.name

    loaded = _colmap_outputs(out)
    placed, _ = poison_points(out / "attack" / "poison_points.ply")
    xyz = loaded.metadata["points3D_xyz"].double().numpy()
    assert xyz.shape == (n_points + n, 3) and len(placed) == n
    np.testing.assert_allclose(xyz[n_points:], placed, atol=1e-4)
    np.testing.assert_allclose(xyz[:n_points], clean.metadata["points3D_xyz"].double().numpy(), atol=1e-5)
    np.testing.assert_allclose(
        loaded.cameras.camera_to_worlds.numpy(), clean.cameras.camera_to_worlds.numpy(), atol=1e-6
    )
