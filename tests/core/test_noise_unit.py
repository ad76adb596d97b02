"""The unit of the epipolar distance follows the detector's noise measured in the data
(:func:`mvm.core.affinity.measured_unit_factor`): a noisy detector keeps its true matches, a
precise one keeps the unit of ``distance_scale``."""
import numpy as np

from mvm.core.affinity import MAX_NOISE_FACTOR, measured_unit_factor, with_measured_unit
from mvm.core.config import Config
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.sim.detector import DetectorErrors, pose_scores
from mvm.sim.rig import detect_views, ring_cameras, walking_people


def _capture(noise: float, instants: int = 30, people: int = 1, seed: int = 0):
    """A 4-camera ring seeing ``people`` walking, detections with Gaussian noise of ``noise``
    person sizes and nothing else wrong."""
    cameras = ring_cameras(4)
    rng = np.random.default_rng(seed)
    truth = walking_people(people, instants, rng)
    errors = DetectorErrors(noise=noise, dropout=0.0, occlusion=False, swap_prob=0.0, outlier_joint_prob=0.0,
                            false_pose_rate=0.0)
    kps, cams, inst = [], [], []
    for t in range(instants):
        k, c, _ = detect_views(cameras, truth[t], rng, errors)
        kps.append(k)
        cams.append(c)
        inst.append(np.full(len(c), t))
    keypoints = np.concatenate(kps)
    return cameras, rig_poses(keypoints, np.concatenate(inst), np.concatenate(cams), pose_scores(keypoints)), truth


def test_a_precise_detector_keeps_the_unit_and_a_noisy_one_grows_it_with_its_noise():
    config = Config()
    precise = measured_unit_factor(*_capture(0.005)[:2], config)
    noisy = measured_unit_factor(*_capture(0.05)[:2], config)
    noisier = measured_unit_factor(*_capture(0.08)[:2], config)
    assert precise == 1.0
    assert 1.5 < noisy < noisier <= MAX_NOISE_FACTOR
    # Held: a quartile of 0 keeps distance_scale whatever the noise.
    assert measured_unit_factor(*_capture(0.08)[:2], config.replace(distance_quartile=0)) == 1.0
    folded = with_measured_unit(*_capture(0.05)[:2], config)
    assert folded.distance_quartile == 0 and np.isclose(folded.distance_scale, config.distance_scale * noisy)


def test_a_noisy_detector_is_found_in_every_instant_where_the_fixed_unit_loses_it():
    """Joints 5 % of the person's size off (a small model on large frames): with the unit held
    at 1 % of the focal length, true matches fall outside the gate and the person is lost in
    many instants; with the measured unit it is found in every one, where it truly is."""
    cameras, poses, truth = _capture(0.05, instants=40)
    held = reconstruct_instants(cameras, poses, Config(refine=False, distance_quartile=0), workers=1)
    measured = reconstruct_instants(cameras, poses, Config(refine=False), workers=1)
    found_held = len(np.unique(held.instant))
    assert found_held <= 34, found_held
    assert len(measured) == 40 and len(np.unique(measured.instant)) == 40
    error = np.nanmean(np.linalg.norm(measured.X - truth[measured.instant, 0], axis=-1))
    assert error < 0.1, error                      # the noise: 5 % of a 1.7 m person, four views, no refinement


def test_a_rig_refinement_weighs_bones_and_prior_by_the_capture_noise():
    """The rig's refinement measures residuals in the capture's noise units, as a scene's does:
    with a noisy detector the track's bones and the prior weigh more against the keypoints, and the
    bones come out steadier without moving the joints away from the truth."""
    from mvm.core.prior import load_prior
    from mvm.metrics.tracks import limb_length_std
    from mvm.rig.reconstruct_rig import instants_config, rig_config
    from mvm.rig.skeleton import capture_noise_factor, refine_tracks

    config = instants_config(rig_config())
    cameras, poses, truth = _capture(0.005, instants=40)
    precise = reconstruct_instants(cameras, poses, config, workers=1)
    assert capture_noise_factor(precise, poses, config) == 0.5               # below the settings' noise: the bound
    cameras, poses, truth = _capture(0.05, instants=40)
    persons = reconstruct_instants(cameras, poses, config, workers=1)
    noise = capture_noise_factor(persons, poses, config)
    assert 1.3 < noise <= 2.0
    track = np.zeros(len(persons), int)
    prior = load_prior(Config())
    plain = refine_tracks(persons, track, poses, cameras, Config(), prior, noise=1.0)
    units = refine_tracks(persons, track, poses, cameras, Config(), prior, noise=noise)
    std_plain, std_units = np.nanmean(limb_length_std(plain.X)), np.nanmean(limb_length_std(units.X))
    assert std_units < 0.8 * std_plain, (std_units, std_plain)
    true = truth[persons.instant, 0]
    err_plain = np.nanmean(np.linalg.norm(plain.X - true, axis=-1))
    err_units = np.nanmean(np.linalg.norm(units.X - true, axis=-1))
    assert err_units < err_plain + 0.002, (err_units, err_plain)


def test_a_rig_cluster_no_three_cameras_agree_on_is_refused_even_where_few_cameras_look():
    """Five false poses of a rig instant that triangulate to a body which only six cameras see,
    with no joint that three of them agree on, are refused although they explain most of those
    six cameras; a person of the same cameras with a joint three of them agree on is kept."""
    from mvm.core.support import drop_unsupported
    from mvm.core.triangulate import Triangulation

    cameras = ring_cameras(6, radius=4.5)
    X = np.zeros((2, 17, 3))
    X[:, :, 2] = np.linspace(1.7, 0.1, 17)                       # a standing body at the ring's centre
    X[:, :, 0] = np.linspace(-0.2, 0.2, 17)
    inliers = np.zeros((2, 6, 17), bool)
    inliers[:, :2] = True                                        # every joint seen by two cameras
    inliers[1, 2, 5] = True                                      # the person's left shoulder by a third
    tri = Triangulation(X.copy(), inliers, inliers.copy(), np.full((2, 17), 10.0), np.full(2, 0.12))
    drop_unsupported(cameras, [np.arange(5), np.arange(5, 10)], tri, Config().for_driver("rig"))
    assert np.isnan(tri.X[0]).all() and not tri.inliers[0].any()
    assert np.isfinite(tri.X[1]).all()
