"""The detachment of a group of Gaussians (stealth_ns.scan.attachment): pure geometry."""

import math

import numpy as np

from stealth_ns.scan.attachment import OPAQUE_GAUSSIAN, detachment, drawing_region, is_detached, scene_anchors


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A wall of 2000 Gaussians at z = 10 (x, y in [-5, 5]), a camera at the origin looking at it."""
    wall = np.column_stack([rng.uniform(-5, 5, (2000, 2)), np.full(2000, 10.0)])
    return wall, np.ones(len(wall))


def test_a_cloud_floating_before_the_camera_is_far_from_the_scene_a_box_on_the_wall_is_not():
    rng = np.random.default_rng(0)
    wall, wall_opacity = _scene(rng)
    floating = rng.normal([0.0, 0.0, 2.0], 0.1, (300, 3))  # 2 units from the camera, 8 from the wall
    box = rng.uniform([1.0, 1.0, 8.0], [2.0, 2.0, 9.9], (300, 3))  # reaching back to the wall
    means = np.vstack([wall, floating, box])
    opacity = np.concatenate([wall_opacity, np.ones(600)])
    flagged = np.zeros(len(means), dtype=bool)
    flagged[len(wall) :] = True
    anchors = scene_anchors(means, opacity, flagged)
    camera = np.zeros(3)
    is_floating = np.zeros(len(means), dtype=bool)
    is_floating[len(wall) : len(wall) + 300] = True
    free = detachment(means, opacity, is_floating, camera, anchors)
    assert 3.5 < free < 4.5  # ~8 units to the wall over ~2 to the camera
    attached = detachment(means, opacity, flagged & ~is_floating, camera, anchors)
    assert attached < 0.2  # at most ~2 units to the wall over ~9 to the camera
    assert is_detached(free, 0.5) and not is_detached(attached, 0.5) and is_detached(attached, 0.0)


def test_only_opaque_gaussians_are_measured_and_hold_the_scene():
    rng = np.random.default_rng(1)
    wall, wall_opacity = _scene(rng)
    floating = rng.normal([0.0, 0.0, 2.0], 0.1, (50, 3))
    # a transparent veil of unflagged Gaussians around the floating cloud holds nothing up
    veil = rng.normal([0.0, 0.0, 2.0], 0.2, (50, 3))
    means = np.vstack([wall, floating, veil])
    opacity = np.concatenate([wall_opacity, np.ones(50), np.full(50, OPAQUE_GAUSSIAN / 2)])
    flagged = np.zeros(len(means), dtype=bool)
    flagged[len(wall) : len(wall) + 50] = True
    anchors = scene_anchors(means, opacity, flagged)
    assert detachment(means, opacity, flagged, np.zeros(3), anchors) > 3.0
    opacity[len(wall) : len(wall) + 50] = OPAQUE_GAUSSIAN / 2  # the group transparent: nothing to measure
    assert math.isinf(detachment(means, opacity, flagged, np.zeros(3), anchors))


def test_no_scene_to_attach_to_is_no_evidence_of_attachment():
    means = np.random.default_rng(2).normal(size=(20, 3))
    opacity = np.ones(20)
    flagged = np.ones(20, dtype=bool)
    anchors = scene_anchors(means, opacity, flagged)
    assert anchors is None
    assert math.isinf(detachment(means, opacity, flagged, np.full(3, 5.0), anchors))


def test_the_gaussians_drawing_a_region_are_those_in_front_whose_centre_falls_in_it():
    # a camera at the origin looking down +z (OpenCV), 100 pixels focal, 40 x 30 image
    viewmat, K = np.eye(4), np.array([[100.0, 0.0, 20.0], [0.0, 100.0, 15.0], [0.0, 0.0, 1.0]])
    region = np.zeros((30, 40), dtype=bool)
    region[10:20, 20:30] = True
    means = np.array([
        [0.05, 0.0, 1.0],  # pixel (25, 15): inside
        [0.05, 0.0, -1.0],  # behind the camera
        [-0.1, 0.0, 1.0],  # pixel (10, 15): outside the region
        [0.5, 0.0, 1.0],  # pixel (70, 15): outside the image
        [0.05, 0.0, 1.0],  # inside, but not a member
    ])  # fmt: skip
    members = np.array([True, True, True, True, False])
    assert drawing_region(means, members, viewmat, K, region).tolist() == [True, False, False, False, False]
