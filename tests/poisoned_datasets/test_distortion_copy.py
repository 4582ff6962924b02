"""Poisoned copies of datasets whose cameras have lens distortion (the fox capture's OPENCV k1, k2, p1,
p2): nerfstudio trains on undistorted, cropped images, the copy must hold the change on the source's
pixels (a 134x239 composite in a 135x240 dataset stopped the victim's ns-train)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.record import AttackRecord
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image
from stealth_ns.poisoned_datasets.data_only import poison_dataset
from stealth_ns.poisoned_datasets.distortion import change_in_source_frame
from stealth_ns.scene_generator import make_scene

W, H = 64, 48
K = np.array([[60.0, 0.0, 31.3], [0.0, 59.0, 24.6], [0.0, 0.0, 1.0]])
DISTORTION = np.array([0.06, -0.08, 0.0, 0.0, -0.001, 0.0002])  # nerfstudio's (k1, k2, k3, k4, p1, p2)


def _nerfstudio_undistort(image: np.ndarray) -> np.ndarray:
    """nerfstudio's own undistortion of one image with the camera above (its datamanager's function)."""
    from nerfstudio.cameras.cameras import Cameras, CameraType
    from nerfstudio.data.datamanagers.full_images_datamanager import _undistort_image

    camera = Cameras(
        camera_to_worlds=torch.eye(4)[None, :3], fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]),
        cy=float(K[1, 2]), width=W, height=H, camera_type=CameraType.PERSPECTIVE,
        distortion_params=torch.tensor(DISTORTION, dtype=torch.float32)[None],
    )[0]  # fmt: skip
    _, out, _ = _undistort_image(camera, DISTORTION.copy(), {}, image, K.copy())
    return out


def test_a_change_mapped_back_comes_out_of_nerfstudios_undistortion():
    rng = np.random.default_rng(0)
    source = rng.uniform(60, 190, (H, W, 3)).astype(np.float32)
    clean = _nerfstudio_undistort(source)
    h, w = clean.shape[:2]
    assert (h, w) != (H, W)  # the crop happened
    change = np.zeros((h, w, 3), np.float32)
    change[12:30, 20:44] = [50.0, -40.0, 25.0]  # a patch well inside the frame
    back = change_in_source_frame(change, K, DISTORTION, W, H)
    assert back.shape == (H, W, 3)
    again = _nerfstudio_undistort(source + back) - clean
    inner = (slice(14, 28), slice(22, 42))  # away from the patch's edges (bilinear sampling, twice)
    np.testing.assert_allclose(again[inner], change[inner], atol=1.0)
    far = np.ones((h, w), bool)
    far[8:34, 16:48] = False
    assert np.abs(again[far]).max() < 1.0  # nothing leaks away from the patch
    assert np.abs(back).max() <= 50.0  # bilinear: never beyond the change's own bound (an L-inf ball holds)


def test_a_zero_change_is_zero_and_a_wrong_size_is_refused():
    clean = _nerfstudio_undistort(np.zeros((H, W, 3), np.float32))
    assert not change_in_source_frame(np.zeros_like(clean), K, DISTORTION, W, H).any()
    with pytest.raises(StealthNSError, match="cannot map the change back"):
        change_in_source_frame(np.zeros((H, W, 3), np.float32), K, DISTORTION, W, H)


@pytest.fixture(scope="module")
def distorted_scene(tmp_path_factory) -> Path:
    """A 12-view orbit scene whose transforms.json declares OPENCV lens distortion."""
    out = tmp_path_factory.mktemp("distorted") / "scene"
    make_scene(preset="orbit", output=out, resolution="48x36", views=12, seed=0)
    meta = json.loads((out / "transforms.json").read_text())
    meta.update(camera_model="OPENCV", k1=0.05, k2=-0.06, p1=-0.001, p2=0.0002)
    (out / "transforms.json").write_text(json.dumps(meta))
    return out


def test_data_only_copy_of_a_distorted_dataset_trains(distorted_scene, tmp_path):
    out = tmp_path / "poisoned"
    poison_dataset(distorted_scene, out, AttackConfig(view_noise=False, noise_decay="constant"))
    record = AttackRecord.read(out / "attack")
    (view,) = record.views
    written = read_image(out / view.name, "poisoned view")
    source = read_image(distorted_scene / view.name, "source view")
    assert written.shape == source.shape  # the file keeps the dataset's size
    changed = np.abs(written.astype(int) - source.astype(int)).max(-1) > 0
    assert 0 < changed.mean() < 0.9  # the illusion, not the whole frame
    assert "lens distortion" in record.poisoned_dataset["images_written"][view.name]["change"]

    # nerfstudio's datamanager loads the copy (it stopped on the cropped composite before), and what the
    # victim trains on for that view is the composite, up to the resampling of the mapping back and forth
    from scipy.ndimage import binary_erosion

    from stealth_ns.poisoned_datasets.dataset_copy import open_source
    from stealth_ns.poisoned_datasets.setup import setup_pipeline, trainer_config

    pipeline = setup_pipeline(trainer_config(open_source(out), AttackConfig(enabled=False)))
    trained_on = pipeline.datamanager.cached_train[view.index]["image"].numpy()[..., :3].astype(float)
    target = view.target.numpy() * 255.0
    assert trained_on.shape == target.shape
    inner = binary_erosion(view.mask.numpy(), iterations=2)
    assert inner.sum() > 20
    assert np.median(np.abs(trained_on - target)[inner]) < 6.0
