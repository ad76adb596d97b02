"""Completion of people against ground truth: joints hidden in some instants of a walking person
(interpolation), joints never seen in real CMU Panoptic poses (the pose prior's conditional)."""
import numpy as np
import pytest

from mvm.core.completion import (
    FLAG_NAMES,
    INFERRED,
    INTERPOLATED,
    MISSING,
    OBSERVED,
    complete_persons,
    complete_tracks,
    flag_names,
    interpolate_series,
    parse_flags,
)
from mvm.core.prior import PosePrior
from mvm.sim.rig import walking_people

from helpers import SHARED_DATA, cmu_walk

PANOPTIC = SHARED_DATA / "panoptic" / "160906_band1"


@pytest.fixture(scope="module")
def prior():
    return PosePrior.load()


@pytest.fixture(scope="module")
def real_poses():
    if not PANOPTIC.is_dir():
        pytest.skip(f"real Panoptic poses absent: {PANOPTIC}")
    from mvm.eval.panoptic import load_sample

    X = np.concatenate(load_sample(PANOPTIC).poses)
    return X[np.isfinite(X).all((1, 2))]                                  # complete true poses, metres


@pytest.fixture(scope="module")
def real_walk():
    return cmu_walk(z_up=False)


def test_hidden_joint_interpolated_within_2cm(real_walk):
    """The fastest joints of a real walk (wrists, ankles) hidden for 2 instants, all along it."""
    T = len(real_walk)
    errors = []
    for start in range(2, T - 5, 2):
        hidden = real_walk.copy()
        hidden[start:start + 2, [9, 10, 15, 16]] = np.nan
        filled, interpolated = interpolate_series(hidden, max_gap=5)
        assert interpolated.sum() == 8 and interpolated[start:start + 2, [9, 10, 15, 16]].all()
        assert (filled[~interpolated] == real_walk[~interpolated]).all()     # observed joints untouched
        errors.append(np.linalg.norm(filled - real_walk, axis=-1)[interpolated])
    errors = np.concatenate(errors)
    assert errors.max() < 0.02 and errors.mean() < 0.01


def test_interpolation_keeps_to_its_limit_and_never_extrapolates():
    series = np.zeros((20, 17, 3)) + np.arange(20)[:, None, None]
    series[:3, 0] = np.nan                                                # before the first observation
    series[5:15, 1] = np.nan                                              # 10 instants: longer than the limit
    series[17:, 2] = np.nan                                               # after the last
    filled, interpolated = interpolate_series(series, max_gap=9)
    assert not interpolated.any() and np.isnan(filled[:3, 0]).all() and np.isnan(filled[5:15, 1]).all()
    filled, interpolated = interpolate_series(series, max_gap=10)
    assert interpolated[:, 1].sum() == 10 and np.allclose(filled[5:15, 1], series[5:15, 0])
    with pytest.raises(ValueError, match="max_gap"):
        interpolate_series(series, -1)


@pytest.mark.parametrize("joint, bound_m", [(0, 0.05), (7, 0.10), (13, 0.10), (15, 0.15)])
def test_never_seen_joint_inferred_from_the_prior(real_poses, prior, joint, bound_m):
    """A joint missing from every pose: the prior's conditional given the 16 others, median error
    within ``bound_m`` (nose 5 cm, elbow and knee 10 cm, ankle 15 cm). These poses are among the
    prior's training poses, so the bound is an in-sample one; it is also well below what the
    prior's mean pose alone gives."""
    hidden = real_poses.copy()
    hidden[:, joint] = np.nan
    completed, flags = complete_persons(hidden, prior)
    assert (flags[:, joint] == INFERRED).all()
    assert (flags[:, np.arange(17) != joint] == OBSERVED).all()
    error = np.linalg.norm(completed[:, joint] - real_poses[:, joint], axis=-1)
    assert np.median(error) < bound_m
    # the same joint taken from the component mean aligned on the body: the conditional does better
    from mvm.core.completion import _frame_from_means

    means = prior.means.reshape(-1, 17, 3)
    baseline = np.array([np.linalg.norm(_frame_from_means(h, means)[joint] - t[joint])
                         for h, t in zip(hidden, real_poses)])
    assert np.median(error) < np.median(baseline)


def test_frame_joint_never_seen_is_inferred(real_poses, prior):
    """A hip missing: the canonical frame is first given from the prior's means, then conditioned."""
    hidden = real_poses.copy()
    hidden[:, 11] = np.nan
    completed, flags = complete_persons(hidden, prior)
    assert (flags[:, 11] == INFERRED).all()
    error = np.linalg.norm(completed[:, 11] - real_poses[:, 11], axis=-1)
    assert np.median(error) < 0.2


def test_complete_tracks_uses_time_then_the_prior(prior):
    truth = walking_people(2, 30, np.random.default_rng(1))                 # (T, 2, 17, 3)
    X = truth.reshape(-1, 17, 3).copy()
    instant = np.repeat(np.arange(30), 2)
    track = np.tile([0, 1], 30)
    X[(instant >= 5) & (instant < 8) & (track == 0), 12] = np.nan          # short gap: time
    X[track == 1, 16] = np.nan                                            # never seen: the prior
    X[(instant == 12) & (track == 0), :13] = np.nan                        # too little left at one instant
    out, flags = complete_tracks(X, instant, track, max_gap=5, prior=prior)
    assert (flags[(instant >= 5) & (instant < 8) & (track == 0), 12] == INTERPOLATED).all()
    assert (flags[track == 1, 16] == INFERRED).all()
    assert (flags[(instant == 12) & (track == 0)] == INTERPOLATED).sum() == 13   # time fills the lost joints
    assert np.isfinite(out).all()
    err = np.linalg.norm(out - truth.reshape(-1, 17, 3), axis=-1)
    assert err[flags == INTERPOLATED].mean() < 0.02 and err[flags == INTERPOLATED].max() < 0.12   # arms swing 0.5 m
    # without a prior the never-seen joint stays missing
    _, flags = complete_tracks(X, instant, track, max_gap=5)
    assert (flags[track == 1, 16] == MISSING).all()


def test_too_little_of_a_person_stays_missing(prior):
    X = np.full((1, 17, 3), np.nan)
    X[0, :2] = [[0, 0, 1.6], [0.03, 0.08, 1.66]]
    out, flags = complete_persons(X, prior)
    assert (flags[0, :2] == OBSERVED).all() and (flags[0, 2:] == MISSING).all() and np.isnan(out[0, 2:]).all()


def test_flag_names_round_trip():
    flags = np.array([[OBSERVED, INTERPOLATED, INFERRED, MISSING]])
    assert flag_names(flags) == [["observed", "interpolated", "inferred", "missing"]]
    assert parse_flags(flag_names(flags)[0]).tolist() == flags[0].tolist()
    with pytest.raises(ValueError, match="guessed"):
        parse_flags(["observed", "guessed"])
    assert FLAG_NAMES[OBSERVED] == "observed"


def test_hand_held_scene_completed_flagged_and_exported(tmp_path, prior):
    """A mannequin scene whose detector never reports a left ankle: `complete` infers it from the
    prior for every person (within 15 cm median of the truth), poses3d.json keeps the flags, and
    the exported supervision carries them per keypoint."""
    import json

    from mvm.core.config import Config
    from mvm.core.reconstruct import reconstruct
    from mvm.io.scene_dir import poses3d_document, read_poses3d, write_poses3d
    from mvm.metrics.poses import match_persons
    from mvm.net.supervision import export_supervision
    from mvm.sim.simulate import SimConfig, simulate

    scene, truth = simulate(SimConfig(people=3, frames=30, seed=4))
    scene.poses.keypoints[:, 15] = 0.0
    plain = reconstruct(scene, Config(refine=False))
    assert np.isnan(plain.persons.keypoints3d[:, 15]).all() and plain.persons.flags is None
    result = reconstruct(scene, Config(refine=False, complete=True), prior=prior)
    persons = result.persons
    assert (persons.flags[:, 15] == INFERRED).all() and np.isfinite(persons.keypoints3d).all()
    assert ((persons.flags == OBSERVED) == np.isfinite(plain.persons.keypoints3d).all(-1)).all()
    pairs = match_persons(persons.keypoints3d, truth.poses3d, 0.5)
    error = [np.linalg.norm(persons.keypoints3d[p, 15] - truth.poses3d[g, 15]) for p, g in pairs]
    assert len(pairs) == 3 and np.median(error) < 0.15
    path = tmp_path / "poses3d.json"
    write_poses3d(path, poses3d_document(persons, scene.poses, result.metrics))
    back = read_poses3d(path)
    assert (back.flags == persons.flags).all()
    document = json.loads(path.read_text())
    document["persons"][0]["flags"][3] = "missing"                        # coordinates present: refused
    path.write_text(json.dumps(document))
    from mvm.errors import InputError

    with pytest.raises(InputError, match=r"persons\[0\]\.flags\[3\]"):
        read_poses3d(path)
    annotations = [a for a in json.loads(export_supervision([(scene, back)], tmp_path / "sup", link="none")
                                         .read_text())["annotations"] if a["num_keypoints"]]   # not ignore boxes
    names = {n for a in annotations for n, v in zip(a["keypoint_flags"], a["keypoints"][2::3]) if v > 0}
    assert names == {"observed", "inferred"}
    assert all(f == "missing" for a in annotations
               for f, v in zip(a["keypoint_flags"], a["keypoints"][2::3]) if v == 0)
    # export completes persons itself when asked, from a poses3d.json without flags
    plain_annotations = json.loads(export_supervision([(scene, plain.persons)], tmp_path / "sup2", link="none",
                                                      prior=prior).read_text())["annotations"]
    assert any("inferred" in a.get("keypoint_flags", ()) for a in plain_annotations)


def test_conditional_mean_is_the_mixture_of_gaussian_conditionals():
    """Against the textbook formula with scipy: per component ``μ_m + Σ_mo Σ_oo⁻¹ (x_o − μ_o)``,
    weighted by the posterior of the components given the present joints."""
    from scipy.linalg import cho_factor, cho_solve
    from scipy.stats import multivariate_normal

    from mvm.core.completion import conditional_mean

    rng = np.random.default_rng(7)
    a = rng.normal(0, 0.3, (2, 51, 51))
    prior = PosePrior(np.array([0.3, 0.7]), rng.normal(0, 0.5, (2, 51)),
                      a @ np.swapaxes(a, 1, 2) / 51 + 0.05 * np.eye(51))
    x = rng.normal(0, 0.5, (3, 17, 3))
    x[0, [3, 4]] = np.nan
    x[1, [3, 4]] = np.nan
    x[2, 10:] = np.nan
    out = conditional_mean(prior, x)
    for p in range(3):
        o = np.repeat(np.isfinite(x[p]).all(-1), 3)
        xo = x[p].reshape(-1)[o]
        dens = np.array([w * multivariate_normal(mu[o], S[np.ix_(o, o)]).pdf(xo)
                         for w, mu, S in zip(prior.weights, prior.means, prior.covariances)])
        expected = sum(r * (mu[~o] + S[np.ix_(~o, o)] @ cho_solve(cho_factor(S[np.ix_(o, o)]), xo - mu[o]))
                       for r, mu, S in zip(dens / dens.sum(), prior.means, prior.covariances))
        np.testing.assert_allclose(out[p].reshape(-1)[~o], expected, rtol=1e-9, atol=1e-12)
        assert np.array_equal(out[p].reshape(-1)[o], xo)
