"""Rig: instants are independent blocks of the core, reconstruction against ground truth, tracking,
smoothing."""
import numpy as np
import pytest

from mvm.core.camera import project_views
from mvm.core.config import Config
from mvm.core.pipeline import match
from mvm.core.scene import Poses2D
from mvm.metrics.poses import match_persons, pose_errors
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.tracking import link_tracks, smooth_series
from mvm.sim.rig import DetectorErrors, detect_views, pose_scores, ring_cameras, walking_people


def _capture(cameras, T=12, people=4, seed=0, errors=DetectorErrors()):
    rng = np.random.default_rng(seed)
    truth = walking_people(people, T, rng)
    kps, cams, inst = [], [], []
    for t in range(T):
        k, c, _ = detect_views(cameras, truth[t], rng, errors)
        kps.append(k), cams.append(c), inst.append(np.full(len(c), t))
    kp = np.concatenate(kps)
    return truth, rig_poses(kp, np.concatenate(inst), np.concatenate(cams), pose_scores(kp))


def test_instants_are_matched_as_separate_scenes():
    """A batch of instants is one call of the core; its groups are those of each instant alone."""
    cameras = ring_cameras(6)
    _, det = _capture(cameras, T=3)
    config = Config()
    batch = match(cameras, det, config)
    alone = []
    for t in range(3):
        rows = np.flatnonzero(det.instant == t)
        single = Poses2D(det.keypoints[rows], det.view[rows], det.ids[rows], det.score[rows])
        alone += [rows[g] for g in match(cameras, single, config)]
    assert len(batch) >= 3 * 4 - 1
    assert [g.tolist() for g in batch] == [g.tolist() for g in alone]
    for g in batch:
        assert len(np.unique(det.instant[g])) == 1 and len(np.unique(det.view[g])) == len(g)


@pytest.mark.parametrize("batch_size", [5, 64])
def test_reconstruction_matches_truth(batch_size):
    cameras = ring_cameras(5)
    truth, det = _capture(cameras, T=12)
    persons = reconstruct_instants(cameras, det, Config(refine=False), batch_size=batch_size)
    found, errors = 0, []
    for t in range(12):
        X = persons.X[persons.instant == t]
        pairs = match_persons(X, truth[t], 0.15)
        found += len(pairs)
        errors.append(pose_errors(X, truth[t], pairs)["mpjpe"])
    assert found >= 0.95 * 12 * 4
    assert np.nanmean(errors) < 0.04                                   # metres
    # members point at the detections used, one per camera at most, from the person's instant
    used = persons.members[persons.members >= 0]
    assert len(np.unique(used)) == len(used)
    q, v = np.nonzero(persons.members >= 0)
    assert (det.instant[persons.members[q, v]] == persons.instant[q]).all()
    assert (det.view[persons.members[q, v]] == v).all()


def test_tracks_survive_gaps_and_split_far_jumps():
    rng = np.random.default_rng(0)
    base = rng.normal(size=(3, 17, 3))
    base[:, :, 0] += np.array([0.0, 3.0, 6.0])[:, None]               # three people 3 m apart
    X, inst, who = [], [], []
    for t in range(20):
        for g in range(3):
            if g == 1 and 8 <= t < 11:                                  # person 1 unseen for 3 instants
                continue
            X.append(base[g] + 0.01 * t)
            inst.append(t)
            who.append(g)
    X, inst, who = np.array(X), np.array(inst), np.array(who)
    order = rng.permutation(len(X))                                     # input order must not matter
    track = link_tracks(X[order], inst[order], 0.5, max_gap=5)
    for g in range(3):
        assert len(np.unique(track[who[order] == g])) == 1
    assert len(np.unique(track)) == 3
    short_gap = link_tracks(X, inst, 0.5, max_gap=2)
    assert len(np.unique(short_gap[who == 1])) == 2                    # the gap exceeds max_gap


@pytest.mark.parametrize("method", ["butterworth", "savgol"])
def test_smoothing_reduces_noise(method):
    rng = np.random.default_rng(0)
    t = np.arange(120) / 30.0
    clean = np.stack([np.sin(t), np.cos(t), t], -1)[:, None].repeat(17, 1)
    noisy = clean + rng.normal(0, 0.01, clean.shape)
    noisy[50:53, 3] = np.nan                                            # a gap
    smooth = smooth_series(noisy, method, rate=30.0, cutoff_hz=3.0, window=11)
    ok = np.isfinite(noisy).all(-1)
    assert np.isnan(smooth[50:53, 3]).all()
    assert np.abs(smooth - clean)[ok].mean() < 0.6 * np.abs(noisy - clean)[ok].mean()


@pytest.mark.parametrize("association", ["3d", "paper"])
def test_false_poses_agreeing_in_three_of_fifteen_cameras_are_refused(association):
    """A cluster of false poses: a body that three of fifteen cameras around the people see
    (low confidence), none of the others, at every instant. The true persons are found, the
    cluster is not (with support 0.2 it was: 3 of 15 cameras)."""
    cameras = ring_cameras(15)
    truth, det = _capture(cameras, T=4, people=3, seed=2)
    ghost = truth[0][0] + np.array([1.6, -1.2, 0.0])                  # (17, 3), away from everyone
    uv, _ = project_views(cameras, ghost)                              # (15, 17, 2)
    ghost_kp = np.concatenate([uv[[0, 5, 10]], np.full((3, 17, 1), 0.4)], -1)
    kp = np.concatenate([det.keypoints] + [ghost_kp] * 4)
    instant = np.concatenate([det.instant, np.repeat(np.arange(4), 3)])
    camera = np.concatenate([det.view, np.tile([0, 5, 10], 4)])
    persons = reconstruct_instants(cameras, rig_poses(kp, instant, camera, pose_scores(kp)),
                                   Config(association=association, refine=False), workers=1)
    for t in range(4):
        X = persons.X[persons.instant == t]
        assert len(match_persons(X, truth[t], 0.15)) == 3
        assert not match_persons(X, ghost[None], 0.3), f"instant {t}: the false poses made a person"
