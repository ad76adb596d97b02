"""One rigid skeleton per track: after the rig's refinement on noisy detections of two people
walking (real CMU motion capture, a rigid skeleton), each track's bone lengths vary by less than
2 % (coefficient of variation), and the lengths are the truth's."""
import numpy as np
import pytest

from mvm.core.config import Config
from mvm.core.keypoints import bone_lengths
from mvm.core.prior import PosePrior
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.skeleton import bone_length_cv, refine_tracks, track_bone_lengths
from mvm.rig.tracking import link_tracks
from mvm.sim.detector import DetectorErrors, pose_scores
from mvm.sim.rig import detect_views, ring_cameras

from helpers import cmu_walk


@pytest.fixture(scope="module")
def capture():
    walk = cmu_walk()
    truth = np.stack([walk[:60], walk[::-1][:60] + [1.2, 0, 0]], 1)          # two people passing
    rng = np.random.default_rng(2)
    cameras = ring_cameras(5)
    kps, cams, inst = [], [], []
    for t in range(len(truth)):
        k, c, _ = detect_views(cameras, truth[t], rng, DetectorErrors(noise=0.01, false_pose_rate=0.0))
        kps.append(k), cams.append(c), inst.append(np.full(len(c), t))
    kp = np.concatenate(kps)
    det = rig_poses(kp, np.concatenate(inst), np.concatenate(cams), pose_scores(kp))
    config = Config()
    persons = reconstruct_instants(cameras, det, config.replace(refine=False))
    track = link_tracks(persons.X, persons.instant, 0.5, 10)
    return cameras, truth, det, config, persons, track


def test_track_bone_lengths_are_robust_medians():
    X = np.repeat(np.array([[[0, 0, 0]] * 17], float), 5, 0)
    X[:, 7] = [0.3, 0, 0]                                                # left shoulder (5) to elbow (7): 0.3
    X[4, 7] = [3.0, 0, 0]                                                # one outlier
    X[2, 5] = np.nan
    lengths = track_bone_lengths(X, np.zeros(5, int))
    assert np.allclose(lengths[:, 0], 0.3)                               # (5, 7) is BONES[0]
    assert np.isnan(track_bone_lengths(X[:2], np.zeros(2, int))[:, 0]).all()   # fewer than 3 instants


def test_bone_lengths_rigid_after_refinement(capture):
    cameras, truth, det, config, persons, track = capture
    prior = PosePrior.load()
    assert len(np.unique(track)) == 2
    rigid = refine_tracks(persons, track, det, cameras, config, prior)       # the default weight
    free = refine_tracks(persons, track, det, cameras, config, prior, bone_weight=0.0)
    cv_rigid = bone_length_cv(rigid.X, track)
    cv_free = bone_length_cv(free.X, track)
    assert np.nanmax(cv_rigid) < 0.02, cv_rigid
    assert np.nanmax(cv_free) > np.nanmax(cv_rigid)
    # lengths close to the truth's
    true_lengths = bone_lengths(truth[0])                                 # (G, B)
    for k in np.unique(track):
        L = np.nanmedian(bone_lengths(rigid.X[track == k]), axis=0)
        assert np.abs(L - true_lengths).mean(1).min() < 0.02
    # the reprojection stays as good as without the term
    assert np.nanmean(rigid.reprojection_error_px) < 1.2 * np.nanmean(free.reprojection_error_px) + 0.5
