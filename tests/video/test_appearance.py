"""The colour descriptor separates differently dressed people under a brightness change, and
appearance helps matching on distinct clothes more than on near-identical ones."""
from __future__ import annotations

import numpy as np
import pytest

from mvm.sim.mannequin_video import RenderConfig, default_people, draw_people, noise_texture, tour_cameras
from mvm.video.appearance import DIM, colour_descriptor, pool_features

SHIRTS = np.array([[40, 40, 200], [200, 60, 40], [40, 180, 60], [30, 200, 220]], dtype=float)      # BGR
TROUSERS = np.array([[120, 40, 40], [40, 40, 40], [150, 150, 150], [30, 90, 140]], dtype=float)


def _frames(brightness: float, view: int):
    rng = np.random.default_rng(1)
    config = RenderConfig(frames=9, width=640, height=360, focal_px=500.0)
    cameras = tour_cameras(config, rng)
    people = default_people(rng, count=len(SHIRTS), spacing=0.8)
    background = np.full((360, 640, 3), 128, np.uint8)
    background[:] = noise_texture(rng, 64)[:36].repeat(10, 0)[:, :64].repeat(10, 1)
    image = draw_people(background.copy(), cameras.P[view], people, SHIRTS, TROUSERS, 500.0)
    image = np.clip(image.astype(float) * brightness, 0, 255).astype(np.uint8)
    X = np.concatenate([people, np.ones(people.shape[:2] + (1,))], axis=2) @ cameras.P[view].T
    kp = np.concatenate([X[..., :2] / X[..., 2:], np.ones(people.shape[:2] + (1,))], axis=2)
    return image, kp


def test_colour_descriptor_tells_people_apart_under_brightness_change():
    image_a, kp_a = _frames(1.0, view=1)
    image_b, kp_b = _frames(0.8, view=7)          # 20% darker, another viewpoint
    a = colour_descriptor(image_a, kp_a)
    b = colour_descriptor(image_b, kp_b)
    assert a.shape == (len(SHIRTS), DIM)
    S = a @ b.T                                      # cosine (unit vectors)
    assert (np.argmax(S, axis=1) == np.arange(len(SHIRTS))).all(), S.round(2)
    margin = np.diag(S) - np.where(np.eye(len(S), dtype=bool), -np.inf, S).max(axis=1)
    assert margin.min() > 0.15, S.round(2)


def test_colour_descriptor_of_missing_pose_is_zero():
    image, kp = _frames(1.0, view=3)
    kp[0, :, 2] = 0.0
    d = colour_descriptor(image, kp)
    assert np.all(d[0] == 0) and np.allclose(np.linalg.norm(d[1:], axis=1), 1)
    with pytest.raises(ValueError, match="image"):
        colour_descriptor(image[..., 0], kp)


def test_pool_features_averages_along_limbs():
    features = np.zeros((2, 20, 20))
    features[0, :, :10] = 1.0   # left half: channel 0
    features[1, :, 10:] = 1.0   # right half: channel 1
    kp = np.zeros((2, 17, 3))
    kp[0, :, 0], kp[1, :, 0] = 30.0, 130.0       # stride 8: cells 3 and 16
    kp[:, :, 1] = np.linspace(10, 150, 17)
    kp[:, :, 2] = 1.0
    pooled = pool_features(features, kp, stride=8)
    assert np.allclose(pooled, [[1, 0], [0, 1]])


def _matching(bank_poses, identical: bool, use_appearance: bool) -> tuple[float, float]:
    from mvm.core.config import Config
    from mvm.core.pipeline import match
    from mvm.metrics.poses import matching_precision_recall
    from mvm.sim.simulate import SimConfig, simulate

    sim = SimConfig(people=8, frames=30, crowd_radius=1.4, min_separation=0.6, identical_clothes=identical,
                    seed=5, image_width=960, image_height=540, focal_px=750.0)
    scene, truth = simulate(sim, bank_poses)
    groups = match(scene.cameras, scene.poses, Config(use_appearance=use_appearance, tau=0.15))
    return matching_precision_recall(groups, truth.person)


def test_appearance_helps_distinct_clothes_more_than_identical(bank_poses, capsys):
    gains = {}
    for identical in (False, True):
        p0, r0 = _matching(bank_poses, identical, False)
        p1, r1 = _matching(bank_poses, identical, True)
        f0, f1 = 2 * p0 * r0 / (p0 + r0), 2 * p1 * r1 / (p1 + r1)
        gains[identical] = f1 - f0
        with capsys.disabled():
            print(f"\nclothes {'identical' if identical else 'distinct'}: F1 without appearance {f0:.4f}, "
                  f"with {f1:.4f} (P {p0:.3f}->{p1:.3f}, R {r0:.3f}->{r1:.3f})")
    assert gains[False] >= gains[True] - 1e-9
    assert gains[False] > 0
