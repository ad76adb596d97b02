"""Limb joints through long occlusions of a rig's tracks (mvm.rig.occlusions, and the refusals of
mvm.rig.refusals), against simulated captures whose occlusions the tests make (a wrist hidden
from every view but one, another from every view, for 25 instants; wrists and arms reported
elsewhere) and tracks they build."""
import numpy as np
import pytest

from mvm.core.camera import project_views
from mvm.core.completion import INFERRED, OBSERVED
from mvm.core.keypoints import INDEX
from mvm.metrics.poses import match_persons
from mvm.rig.instants import reconstruct_instants, rig_poses
from mvm.rig.occlusions import rays
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import completion_prior, instants_config, rig_config, track_and_complete
from mvm.rig.refusals import jump_disputed, spikes, widen_to_steps
from mvm.sim.rig import ring_cameras
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

HIDDEN = range(30, 55)                          # instants
#: (person, joint, views left seeing it)
OCCLUSIONS = ((0, INDEX["right_wrist"], 1), (1, INDEX["left_wrist"], 0))


def _hide(sim):
    """Drop the occluded joints' keypoints in all views but the first ``left`` of them."""
    for g, j, left in OCCLUSIONS:
        rows = (sim.person == g) & np.isin(sim.frame, HIDDEN) & (sim.camera >= left)
        sim.keypoints[rows, j] = 0.0


def _run(sim, options):
    config = rig_config()
    prior = completion_prior(config)
    det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
    cameras = sim.calibration.cameras
    persons = reconstruct_instants(cameras, det, instants_config(config), prior)
    _, persons, X, flags = track_and_complete(persons, options, prior, config, det, cameras)
    found = {}                                   # (person, joint) -> [(instant, error, flag, score)]
    around = []
    for t in HIDDEN:
        rows = np.flatnonzero(persons.instant == t)
        for p, g in match_persons(X[rows], sim.poses3d[t], 0.5):
            q = rows[p]
            d = np.linalg.norm(X[q] - sim.poses3d[t, g], axis=-1)
            for gg, j, _ in OCCLUSIONS:
                if gg == g:
                    found.setdefault(g, []).append((t, d[j], flags[q, j], persons.scores[q, j]))
                    around += d[[j - 2, j - 4]][flags[q, [j - 2, j - 4]] == OBSERVED].tolist()   # elbow, shoulder
    return found, np.mean(around)


@pytest.fixture(scope="module")
def runs():
    sim = simulate_rig(RigSimConfig(cameras=5, people=2, frames=90, distortion=0.0, seed=4))
    _hide(sim)
    return _run(sim, RigOptions(frame_rate=30.0)), _run(sim, RigOptions(frame_rate=30.0, occlusion_max_gap=0))


def test_hidden_wrists_are_inferred_near_the_truth(runs):
    (after, around), (before, _) = runs
    for g, _, left in OCCLUSIONS:
        t, error, flag, score = (np.array(v) for v in zip(*after[g]))
        assert len(t) >= 0.9 * len(HIDDEN)
        assert (flag == INFERRED).all()
        assert ((score > 0) & (score <= 1)).all()
        bound = 0.025 if left else 0.045                     # metres; the joints around: ~0.006
        assert error.mean() < bound, (g, error.mean(), around)
        assert error.mean() < np.mean([e for _, e, _, _ in before[g]])  # better than interpolation


#: (person, joint, views seeing it at its place) of the Shelf-like case: the others report it
#: 20 to 30 cm off through the stretch.
REPORTED_OFF = ((0, INDEX["right_wrist"], 2), (1, INDEX["left_wrist"], 1))


def _report_off(sim, shared: bool = False, arm: bool = False):
    """Move the keypoints of :data:`REPORTED_OFF`'s joints (``arm``: and their elbows, by the
    same offset) in all views but the first ``seen`` to the projection of a point off the
    truth, one offset per view (as a detector reports a hidden hand at something near it), or
    one for all of them (``shared``: the views agree on another thing, the other hand or a
    prop)."""
    rng = np.random.default_rng(8)
    cameras = sim.calibration.cameras
    for g, j, seen in REPORTED_OFF:
        common = rng.normal(size=3)
        for v in range(seen, len(cameras.names)):
            offset = common.copy() if shared else rng.normal(size=3)
            offset *= rng.uniform(0.2, 0.3) / np.linalg.norm(offset)
            rows = np.flatnonzero((sim.person == g) & np.isin(sim.frame, HIDDEN) & (sim.camera == v))
            for k in (j, j - 2) if arm else (j,):
                uv, _ = project_views(cameras.subset([v]), sim.poses3d[sim.frame[rows], g, k] + offset)
                sim.keypoints[rows, k, :2] = uv[0]
                sim.keypoints[rows, k, 2] = np.maximum(sim.keypoints[rows, k, 2], 0.5)


def _errors_with_and_without_fill(sim) -> dict:
    """``{("fill" | "none", person): [errors of its REPORTED_OFF joint over HIDDEN]}``, and
    ``("elbow" | "shoulder", person)``: those of the joint's elbow and shoulder with the fill."""
    errors = {}
    for name, gap in (("fill", RigOptions().occlusion_max_gap), ("none", 0)):
        config = rig_config()
        prior = completion_prior(config)
        det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
        cameras = sim.calibration.cameras
        persons = reconstruct_instants(cameras, det, instants_config(config), prior)
        _, persons, X, _ = track_and_complete(persons, RigOptions(frame_rate=30.0, occlusion_max_gap=gap), prior,
                                              config, det, cameras)
        for t in HIDDEN:
            rows = np.flatnonzero(persons.instant == t)
            for p, g in match_persons(X[rows], sim.poses3d[t], 0.5):
                j = next(j for gg, j, _ in REPORTED_OFF if gg == g)
                d = np.linalg.norm(X[rows[p]] - sim.poses3d[t, g], axis=-1)
                errors.setdefault((name, g), []).append(d[j])
                if name == "fill":
                    errors.setdefault(("elbow", g), []).append(d[j - 2])
                    errors.setdefault(("shoulder", g), []).append(d[j - 4])
    return errors


def test_a_wrist_reported_off_in_most_views_is_refused_and_filled():
    """Shelf-like: a wrist seen at its place in 2 views of 5 (1 for the other person) and
    reported 20-30 cm off in the rest through 25 instants. The triangulation takes wrong
    views; the fill refuses the disputed wrist, keeps the views that agree with the track's
    motion where the stretch begins and ends, and brings it within a few centimetres."""
    sim = simulate_rig(RigSimConfig(cameras=5, people=2, frames=90, distortion=0.0, seed=4))
    _report_off(sim)
    errors = _errors_with_and_without_fill(sim)
    for g, _, seen in REPORTED_OFF:
        after, before = np.mean(errors["fill", g]), np.mean(errors["none", g])
        assert len(errors["fill", g]) >= 0.9 * len(HIDDEN)
        assert after < (0.02 if seen == 2 else 0.035) and after < 0.4 * before, (g, after, before)


def test_a_wrist_the_other_views_agree_is_elsewhere_is_refused_and_filled():
    """As above, but the views that do not see the wrist all report one point 20-30 cm off: the
    triangulation takes it. With one view seeing the wrist, no two views dispute it, but the
    forearm's length does (164 mm without that test); refused, the wrist is filled from the
    views that see it and the track's motion, without the rays of the views that agreed on the
    other thing (57 mm with them). Its elbow, which the refinement's forearm term had pulled
    35 mm towards the other thing, is refined again without it: within 1 cm."""
    sim = simulate_rig(RigSimConfig(cameras=5, people=2, frames=90, distortion=0.0, seed=4))
    _report_off(sim, shared=True)
    errors = _errors_with_and_without_fill(sim)
    for g, _, seen in REPORTED_OFF:
        after, before = np.mean(errors["fill", g]), np.mean(errors["none", g])
        assert len(errors["fill", g]) >= 0.9 * len(HIDDEN)
        assert after < (0.02 if seen == 2 else 0.025) and after < 0.4 * before, (g, after, before)
        assert np.mean(errors["elbow", g]) < 0.01, (g, np.mean(errors["elbow", g]))


def test_an_arm_the_other_views_agree_is_elsewhere_leaves_its_shoulder_in_place():
    """As above, with the elbow moved with the wrist in the views that do not see them (they
    agree on another arm, whose forearm is as long): the elbow's upper arm refuses it, and the
    wrist, which those views alone made, goes with it (218 mm off without that); both are filled
    within a few centimetres. The shoulder, which the refinement's upper-arm term had pulled
    37 mm towards the other elbow, is refined again without it: within 1 cm."""
    sim = simulate_rig(RigSimConfig(cameras=5, people=2, frames=90, distortion=0.0, seed=4))
    _report_off(sim, shared=True, arm=True)
    errors = _errors_with_and_without_fill(sim)
    for g, _, _ in REPORTED_OFF:
        after, before = np.mean(errors["fill", g]), np.mean(errors["none", g])
        assert len(errors["fill", g]) >= 0.9 * len(HIDDEN)
        assert after < 0.03 and after < 0.2 * before, (g, after, before)
        assert np.mean(errors["elbow", g]) < 0.02, (g, np.mean(errors["elbow", g]))
        assert np.mean(errors["shoulder", g]) < 0.01, (g, np.mean(errors["shoulder", g]))


def test_confidence_falls_towards_the_middle_of_an_unseen_gap(runs):
    (after, _), _ = runs
    g = next(g for g, _, left in OCCLUSIONS if left == 0)
    t, _, _, score = (np.array(v) for v in zip(*after[g]))
    middle = np.abs(t - np.mean(HIDDEN)) < 4
    ends = (t == HIDDEN[0]) | (t == HIDDEN[-1])
    assert score[middle].max() < score[ends].min()


def test_rays_pass_through_the_points_they_see():
    cameras = ring_cameras(4)
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (2, 17, 3)) + np.array([0, 0, 1.0])
    uv, _ = project_views(cameras, points)                                     # (V, Q, 17, 2)
    xy = uv.transpose(1, 0, 2, 3)
    conf = np.ones(xy.shape[:-1])
    conf[0, 1, 3] = 0.0
    origin, direction = rays(xy, conf, cameras)
    along = ((points[:, None] - origin) * direction).sum(-1, keepdims=True)
    miss = np.linalg.norm(points[:, None] - origin - along * direction, axis=-1)
    assert np.nanmax(miss) < 1e-9 and (along[np.isfinite(along)] > 0).all()
    assert np.isnan(origin[0, 1, 3]).all() and np.isfinite(origin).sum() == (conf > 0).sum() * 3


def test_the_rays_deviation_is_measured_on_the_capture():
    """Rays through points 3 cm (per axis) from the joints they see: ``ray_sigma`` gives 3 cm; too
    few rays, or joints of two kept keypoints only, give the default; it never goes below the floor."""
    from mvm.rig.occlusions import MIN_RAY_SIGMA_M, RAY_SIGMA_M, ray_sigma

    rng = np.random.default_rng(1)
    centres = ring_cameras(4).centers                                            # (V, 3)
    X = rng.uniform(-0.5, 0.5, (40, 17, 3)) + [0.0, 0.0, 1.0]

    def rays_through(sigma):
        seen = X[:, None] + rng.normal(0.0, sigma, (40, 4, 17, 3))              # (Q, V, 17, 3)
        direction = seen - centres[None, :, None]
        origin = np.broadcast_to(centres[None, :, None], direction.shape)
        return origin, direction / np.linalg.norm(direction, axis=-1, keepdims=True)

    origin, direction = rays_through(0.03)
    used = np.ones((40, 4, 17), bool)
    assert ray_sigma(X, origin, direction, used) == pytest.approx(0.03, rel=0.05)
    assert ray_sigma(X * 1000, origin * 1000, direction, used, unit=1000) == pytest.approx(30, rel=0.05)
    two = used.copy()
    two[:, 2:] = False                                                           # two rays meet wherever
    assert ray_sigma(X, origin, direction, two) == RAY_SIGMA_M
    few = np.zeros_like(used)
    few[:3, :, 0] = True                                                         # 12 rays
    assert ray_sigma(X, origin, direction, few) == RAY_SIGMA_M
    assert ray_sigma(X, *rays_through(1e-4), used) == MIN_RAY_SIGMA_M
    X_missing = X.copy()
    X_missing[:, :16] = np.nan                                                   # 160 rays left
    assert ray_sigma(X_missing, origin, direction, used) == pytest.approx(0.03, rel=0.2)


def _arm_track(T=80):
    """One track: a body standing still, its right forearm swinging about the elbow at a fixed
    length (0.25 m), its upper arm about the shoulder (0.3 m)."""
    t = np.arange(T)
    X = np.tile(np.linspace(0, 1, 17 * 3).reshape(17, 3), (T, 1, 1))           # every joint somewhere
    s, e, w = INDEX["right_shoulder"], INDEX["right_elbow"], INDEX["right_wrist"]
    X[:, s] = [0.2, 0.0, 1.4]
    a = 0.4 * np.sin(2 * np.pi * t / 50)
    X[:, e] = X[:, s] + 0.3 * np.stack([np.sin(a), 0 * a, -np.cos(a)], -1)
    b = a + 0.5 + 0.6 * np.sin(2 * np.pi * t / 35)
    X[:, w] = X[:, e] + 0.25 * np.stack([np.sin(b), 0.3 * np.cos(b), -np.cos(b)], -1) / np.sqrt(
        1 + (0.3 * np.cos(b)) ** 2)[:, None]
    return X, t, np.zeros(T, int)


def test_runs_are_filled_and_flagged_by_length_and_place():
    """A brief run is interpolated, a long one and one at the track's end inferred; an elbow and
    wrist hidden together are both filled, the elbow first. No view sees them: the fills are
    within a few centimetres of the truth, the wrist at its bone's length from the elbow, and the
    confidence falls away from the seen instants."""
    from mvm.core.completion import INTERPOLATED
    from mvm.rig.occlusions import fill_occlusions

    truth, instant, track = _arm_track()
    e, w = INDEX["right_elbow"], INDEX["right_wrist"]
    X = truth.copy()
    X[3:5, w] = np.nan                                   # brief
    X[20:35, w] = np.nan                                 # long
    X[50:62, [e, w]] = np.nan                            # a whole forearm and upper arm
    X[74:, w] = np.nan                                   # the track's end
    no_rays = np.full((len(X), 5, 17, 3), np.nan)
    out, flags, confidence = fill_occlusions(X, instant, track, no_rays, no_rays, None, long_gap=5)
    assert (flags[3:5, w] == INTERPOLATED).all()
    assert (flags[20:35, w] == INFERRED).all() and (flags[74:, w] == INFERRED).all()
    assert (flags[50:62, [e, w]] == INFERRED).all()
    assert (flags[np.isfinite(X).all(-1)] == 0).all() and np.array_equal(out[np.isfinite(X)], X[np.isfinite(X)])
    for rows, j, bound in ((slice(3, 5), w, 0.005), (slice(20, 35), w, 0.03), (slice(50, 62), e, 0.01),
                           (slice(50, 62), w, 0.02), (slice(74, None), w, 0.05)):
        error = np.linalg.norm(out[rows, j] - truth[rows, j], axis=-1)
        assert error.mean() < bound, (rows, j, error.mean())
    bone = np.linalg.norm(out[20:35, w] - out[20:35, e], axis=-1)
    assert np.abs(bone - 0.25).max() < 0.02
    assert ((confidence[flags > 0] > 0) & (confidence[flags > 0] <= 1)).all() and (confidence[flags == 0] == 0).all()
    assert confidence[27, w] < confidence[20, w] and confidence[79, w] < confidence[74, w]


def test_the_prior_guides_a_hidden_wrist_by_its_own_forearm():
    """An elbow and a wrist hidden together for 40 instants, no view seeing them, and a prior
    whose guess of the arm is right in shape but 30 cm off in place (it places a whole arm, not
    its joints one by one): the wrist is filled from the filled elbow along the prior's forearm
    (its offset 21 mm off on average), not towards the prior's wrist (46 mm when taken so)."""
    from mvm.rig.occlusions import fill_occlusions

    truth, instant, track = _arm_track()
    e, w = INDEX["right_elbow"], INDEX["right_wrist"]
    X = truth.copy()
    X[20:60, [e, w]] = np.nan
    guess = truth.copy()
    guess[20:60, [e, w]] += [0.3, 0.0, 0.0]
    no_rays = np.full((len(X), 5, 17, 3), np.nan)
    out, flags, _ = fill_occlusions(X, instant, track, no_rays, no_rays, guess, long_gap=5)
    forearm = (out[20:60, w] - out[20:60, e]) - (truth[20:60, w] - truth[20:60, e])
    assert (flags[20:60, [e, w]] == INFERRED).all()
    assert np.linalg.norm(forearm, axis=-1).mean() < 0.03, np.linalg.norm(forearm, axis=-1).mean()


def test_a_joint_whose_parent_is_unknown_is_left():
    from mvm.rig.occlusions import fill_occlusions

    truth, instant, track = _arm_track(40)
    e, w = INDEX["right_elbow"], INDEX["right_wrist"]
    X = truth.copy()
    X[10:20, w] = np.nan
    X[14, e] = X[14, INDEX["right_shoulder"]] = np.nan      # the elbow cannot be filled at 14
    no_rays = np.full((len(X), 3, 17, 3), np.nan)
    out, flags, _ = fill_occlusions(X, instant, track, no_rays, no_rays)
    assert (flags[10:20, w] == 0).all() and np.isnan(out[10:20, w]).all()


def test_a_shoulder_missing_briefly_is_bridged_so_its_arm_can_be_filled():
    """A shoulder missing at one instant of a wrist's gap: with ``root_gap`` it is interpolated
    first (flagged so), its elbow filled there, and the wrist filled through the whole gap."""
    from mvm.core.completion import INTERPOLATED
    from mvm.rig.occlusions import fill_occlusions

    truth, instant, track = _arm_track(40)
    s, e, w = INDEX["right_shoulder"], INDEX["right_elbow"], INDEX["right_wrist"]
    X = truth.copy()
    X[10:20, w] = np.nan
    X[14, e] = X[14, s] = np.nan
    no_rays = np.full((len(X), 3, 17, 3), np.nan)
    out, flags, _ = fill_occlusions(X, instant, track, no_rays, no_rays, root_gap=2)
    assert flags[14, s] == INTERPOLATED and np.allclose(out[14, s], truth[14, s])
    assert flags[14, e] == INTERPOLATED and (flags[10:20, w] == INFERRED).all()
    assert np.linalg.norm(out[10:20, w] - truth[10:20, w], axis=-1).mean() < 0.03
    assert (flags[np.isfinite(X).all(-1)] == 0).all()



def test_an_arm_is_filled_through_instants_its_track_missed_whole():
    """An elbow and a wrist hidden for 20 instants, the person not reconstructed at all at two
    of them (no row): the arm is filled at every row of the run, carried through the missed
    instants by its motion, as when every instant has a row; nothing is written for the missed
    ones."""
    from mvm.rig.occlusions import fill_occlusions

    truth, instant, track = _arm_track()
    e, w = INDEX["right_elbow"], INDEX["right_wrist"]
    X = truth.copy()
    X[20:40, [e, w]] = np.nan
    no_rays = np.full((len(X), 3, 17, 3), np.nan)
    whole, _, _ = fill_occlusions(X, instant, track, no_rays, no_rays)
    kept = np.setdiff1d(np.arange(len(X)), [27, 33])
    out, flags, _ = fill_occlusions(X[kept], instant[kept], track[kept], no_rays[kept], no_rays[kept])
    run = (instant[kept] >= 20) & (instant[kept] < 40)
    assert (flags[run][:, [e, w]] == INFERRED).all() and run.sum() == 18
    assert np.allclose(out[run][:, [e, w]], whole[kept][run][:, [e, w]], atol=1e-6)
    error = np.linalg.norm(out[run][:, [e, w]] - truth[kept][run][:, [e, w]], axis=-1).mean(0)
    assert error[0] < 0.01 and error[1] < 0.06, error                   # no view: the motion's own limit
def test_refused_parents_are_the_elbows_knees_and_shoulders_of_refused_limb_joints_but_not_the_hips():
    from mvm.rig.refusals import refused_parents

    refused = np.zeros((5, 17), bool)
    refused[0, INDEX["left_wrist"]] = True
    refused[1, [INDEX["right_ankle"], INDEX["right_knee"]]] = True         # the knee is refused itself
    refused[2, INDEX["left_elbow"]] = True
    refused[3, INDEX["left_knee"]] = True                                 # a hip is not refined again
    refused[4, [INDEX["right_wrist"], INDEX["right_elbow"]]] = True
    expected = np.zeros((5, 17), bool)
    expected[0, INDEX["left_elbow"]] = True
    expected[2, INDEX["left_shoulder"]] = True
    expected[4, INDEX["right_shoulder"]] = True
    assert (refused_parents(refused) == expected).all()


def test_a_wrist_made_only_by_the_views_that_made_its_refused_elbow_is_refused_with_it():
    from mvm.rig.refusals import with_refused_elbows

    e, w = INDEX["left_elbow"], INDEX["left_wrist"]
    inliers = np.ones((4, 5, 17), bool)
    inliers[:, 0, [e, w]] = False                              # view 0 sees the arm, the others another
    refused = np.zeros((4, 17), bool)
    refused[:3, e] = True
    inliers[1, 0, w] = True                                    # view 0 agrees on the wrist: not only theirs
    inliers[2, :, w] = False                                   # no wrist: nothing to refuse
    out = with_refused_elbows(refused, inliers)
    assert out[:, w].tolist() == [True, False, False, False]   # the elbow of person 3 is not refused
    assert (out[:, e] == refused[:, e]).all() and out.sum() == 4


def test_the_views_that_agreed_on_a_refused_joint_are_left_out_unless_two_disputed_it():
    from mvm.rig.refusals import agreed_on_refused

    w = INDEX["left_wrist"]
    valid = np.ones((3, 5, 17), bool)
    inliers = valid.copy()
    refused = np.zeros((3, 17), bool)
    refused[:2, w] = True
    inliers[0, 0, w] = False                                   # one view refused: the others agreed
    inliers[1, :2, w] = False                                  # two: they dispute, all kept
    inliers[2, 0, w] = False                                   # not refused: all kept
    out = agreed_on_refused(refused, inliers, valid)
    assert (out[0, :, w] == [False, True, True, True, True]).all()
    assert out.sum() == 4


def test_disputed_limb_joints():
    """A limb joint is disputed where two of its views' keypoints were refused; a head or torso
    joint never; one refused keypoint is a detector's slip, not a dispute."""
    from mvm.rig.refusals import disputed

    valid = np.ones((3, 5, 17), bool)
    inliers = valid.copy()
    w, e, n = INDEX["left_wrist"], INDEX["right_elbow"], INDEX["nose"]
    inliers[0, :2, w] = False                                 # two refused: disputed
    inliers[1, 0, e] = False                                  # one: not
    inliers[2, :3, n] = False                                 # not a limb joint
    inliers[2, 1:3, e] = False
    valid[2, 1:3, e] = False                                  # absent, not refused
    out = disputed(valid & ~inliers)
    assert out[0, w] and out.sum() == 1


def test_close_disputes_fills_short_breaks_of_one_track():
    """An instant with a refused one at most three instants before it and another at most
    three after is refused, and the instant either side of a stretch of three or more so
    closed (not of a lone one), in its own track and joint only."""
    from mvm.rig.refusals import close_disputes

    w = INDEX["left_wrist"]
    instant = np.concatenate([np.arange(30), np.arange(30)])
    track = np.repeat([0, 1], 30)
    refused = np.zeros((60, 17), bool)
    refused[[2, 5], w] = True                                  # 3, 4 between: closed, 1 and 6 grown
    refused[[15, 23], w] = True                                # seven between: not
    refused[30 + 6, w] = True                                  # the other track, alone: not grown
    out = close_disputes(refused, instant, track)
    assert out[1:7, w].all() and not out[16:23, w].any() and out[[15, 23], w].all()
    assert out[36, w] and out[30:, w].sum() == 1 and out.sum() == 9


def _extended(refused_at, refused_views: dict, track=None) -> list[int]:
    """The instants of 30 (one track, or ``track``) at which a left wrist refused at
    ``refused_at`` is refused after :func:`extend_disputes`, with its keypoints refused in
    ``refused_views`` ``{view: instants}`` of 3 views; no other joint is touched."""
    from mvm.rig.refusals import extend_disputes

    w = INDEX["left_wrist"]
    refused = np.zeros((30, 17), bool)
    refused[refused_at, w] = True
    view_refused = np.zeros((30, 3, 17), bool)
    for view, instants in refused_views.items():
        view_refused[instants, view, w] = True
    out = extend_disputes(refused, view_refused, np.arange(30), np.zeros(30, int) if track is None else track)
    assert not np.delete(out, w, axis=1).any()
    return np.flatnonzero(out[:, w]).tolist()


def test_a_dispute_extends_over_one_view_refused_next_to_it_but_not_over_others():
    """A wrist refused at instants 5-7 (its bone off there) whose view 0 was refused from 2 to 11:
    the one view that sees it where the others agree on another thing. The refusal extends over
    2-11; over view 1's refusals at 12-13 (another view, after view 0's run ended) and over
    view 2's lone refusal at 20 (touching no refused instant) it does not."""
    views = {0: list(range(2, 12)), 1: [12, 13], 2: [20]}
    assert _extended(list(range(5, 8)), views) == list(range(2, 12))
    two_tracks = np.r_[np.zeros(9, int), np.ones(21, int)]                 # 0-8 and 9-29: the run is cut at 9
    assert _extended(list(range(5, 8)), views, two_tracks) == list(range(2, 9))


W = INDEX["right_wrist"]


def _wrist_off_from_10_to_19():
    """An arm's track of 40 instants whose right wrist (:data:`W`) sits 30 cm off from 10 to 19:
    ``(truth, X: (40, 17, 3), instant, track, view_refused: (40, 4, 17), refused: (40, 17))``,
    the last two all False."""
    truth, instant, track = _arm_track(40)
    X = truth.copy()
    X[10:20, W] += [0.3, 0.0, 0.0]
    return truth, X, instant, track, np.zeros((40, 4, 17), bool), np.zeros((40, 17), bool)


def test_a_run_of_one_view_refused_where_the_wrist_jumps_is_refused():
    """A wrist whose one view is refused from 10 to 19 while the joint sits 30 cm off from 10 on
    (the other views agree on another thing): the run is refused. The same run without the jump
    (the one view simply wrong), a jump with no view refused, and a run already disputed are not."""
    truth, X, instant, track, view_refused, none = _wrist_off_from_10_to_19()
    view_refused[10:20, 2, W] = True
    assert np.flatnonzero(jump_disputed(X, view_refused, none, instant, track)[:, W]).tolist() == list(range(10, 20))
    assert not jump_disputed(truth, view_refused, none, instant, track).any()
    assert not jump_disputed(X, np.zeros_like(view_refused), none, instant, track).any()
    settled = none.copy()
    settled[12, W] = True
    assert not jump_disputed(X, view_refused, settled, instant, track).any()
    assert np.flatnonzero(jump_disputed(1000 * X, view_refused, none, instant, track, unit=1000.0)[:, W]).size == 10


def test_one_views_refused_run_goes_on_over_short_breaks_but_takes_no_lone_refusal():
    """View 0 refused from 2 to 11 but at 6-7 (its keypoint missing there, or agreeing with the
    others' by chance) beside a wrist refused at 9-10: the refusal extends over 2-11, the break
    included. A lone refusal of view 0 at 13, two instants after the run, is not joined to it
    (one stray keypoint is not the stretch); nor is a run across a break of 4."""
    assert _extended([9, 10], {0: [2, 3, 4, 5, 8, 9, 10, 11, 13]}) == list(range(2, 12))
    assert _extended([9, 10], {0: [2, 3, 4, 9, 10, 11, 13]}) == [9, 10, 11]


def test_a_jump_shortly_before_one_views_refused_run_refuses_it():
    """The wrist sits 30 cm off from 10 to 19, but its one view is refused only from 12 on, with
    a break at 15 (the thing the others report lay along its line of sight there): the run
    12-19 is refused, the break included. With the wrist off from 10 to 29, a run from 15 to 19
    is not: no jump where it begins or ends."""
    _, X, instant, track, view_refused, none = _wrist_off_from_10_to_19()
    view_refused[12:20, 2, W] = True
    view_refused[15, 2, W] = False
    assert np.flatnonzero(jump_disputed(X, view_refused, none, instant, track)[:, W]).tolist() == list(range(12, 20))
    X[20:30, W] += [0.3, 0.0, 0.0]                                          # off from 10 to 29 now
    late = np.zeros_like(view_refused)
    late[15:20, 2, W] = True
    assert not jump_disputed(X, late, none, instant, track).any()


def test_a_refusal_is_widened_to_the_steps_of_the_wrist_around_it():
    """The wrist sits 30 cm off from 10 to 19 and is refused from 12 to 17 (its one view was
    missing at 10-11 and 18-19): the refusal widens to 10-19, where the wrist stepped off and
    back, and no farther (where it flickers back and forth as it steps back, through the
    flicker). Refused at 12-14 only (fewer than half the instants between the
    steps), or with the wrist off from 10 to the track's end (no step back), it is not widened;
    with the wrist lost at 20-21 instead of stepping back, it is where the refusal reaches 19, and
    not where it stops at 17. Off to the end and refused from 12 to 29, most of the instants
    after the step, it is not: the refusal stops short of the track's end."""
    truth, X, instant, track, _, refused = _wrist_off_from_10_to_19()
    refused[12:18, W] = True
    assert np.flatnonzero(widen_to_steps(refused, X, instant, track)[:, W]).tolist() == list(range(10, 20))
    assert np.flatnonzero(widen_to_steps(refused, 1000 * X, instant, track, 1000.0)[:, W]).size == 10
    assert np.array_equal(widen_to_steps(refused, truth, instant, track), refused)
    flicker = X.copy()
    flicker[21, W] += [0.3, 0.0, 0.0]                                       # back at 20, off again at 21, back at 22
    assert np.flatnonzero(widen_to_steps(refused, flicker, instant, track)[:, W]).tolist() == list(range(10, 22))
    few = np.zeros_like(refused)
    few[12:15, W] = True
    assert np.array_equal(widen_to_steps(few, X, instant, track), few)
    X[20:, W] += [0.3, 0.0, 0.0]                                            # off from 10 to the end
    assert np.array_equal(widen_to_steps(refused, X, instant, track), refused)
    X[20:22, W] = np.nan                                                    # lost at 20-21 instead of a step back
    assert np.array_equal(widen_to_steps(refused, X, instant, track), refused)
    refused[18:20, W] = True                                                # refused up to where it is lost
    assert np.flatnonzero(widen_to_steps(refused, X, instant, track)[:, W]).tolist() == list(range(10, 20))
    X[20:22, W] = X[22, W]
    most = np.zeros_like(refused)
    most[12:30, W] = True                                                   # 18 of the 30 after the step
    assert np.array_equal(widen_to_steps(most, X, instant, track), most)


def test_an_instant_between_refusals_of_a_limb_joint_is_refused_with_them():
    """Two views dispute the elbow at 10-12 (refused, and the stretch grown to 9-13), and it is off
    its track at 15 (a spike): 14, between them, is refused with them, as the instants between two
    disputes are. Without the spike nothing is refused past 13; with every view agreeing, nothing."""
    from mvm.rig.refusals import refused_limb_joints

    truth, instant, track = _arm_track(40)
    e = INDEX["right_elbow"]
    X = truth.copy()
    X[15, e] += [0.3, 0.0, 0.0]
    valid = np.ones((40, 4, 17), bool)
    inliers = valid.copy()
    inliers[10:13, :2, e] = False
    refused = refused_limb_joints(X, inliers, valid, instant, track)[:, e]
    assert np.flatnonzero(refused).tolist() == list(range(9, 16))
    refused = refused_limb_joints(truth, inliers, valid, instant, track)
    assert np.flatnonzero(refused[:, e]).tolist() == list(range(9, 14))
    assert not refused_limb_joints(truth, valid, valid, instant, track).any()
    # where the elbow's refusal reaches, at 9 and 13, instants its views agreed on, the wrist they
    # made is refused with it (those views took the arm to the other arm as its stretch began),
    # and closed between; at 10-12 two views disputed the elbow, not the wrist they saw
    assert np.flatnonzero(refused[:, INDEX["right_wrist"]]).tolist() == list(range(9, 14))


def test_a_limb_joint_off_its_track_for_an_instant_or_two_and_back_is_a_spike():
    """The wrist 30 cm off at 5, and at 12-13; the elbow alone 30 cm off at 20 (its wrist, in
    place, is not: it is measured from the shoulder); the whole arm 30 cm off at 28: spikes. The
    wrist off from 32 to the end (a step), three instants off (a stretch), a wrist flickering by
    15 cm (less than ``SPIKE_M``) and the true track are not."""
    truth, instant, track = _arm_track(40)
    E = INDEX["right_elbow"]
    X = truth.copy()
    X[5, W] += [0.3, 0.0, 0.0]
    X[12:14, W] += [0.0, 0.3, 0.0]
    X[20, E] += [0.0, 0.0, 0.3]
    X[24:27, W] += [0.3, 0.0, 0.0]
    X[28, [E, W]] += [0.0, 0.3, 0.0]
    X[32:, W] += [0.0, 0.0, 0.3]
    out = spikes(X, instant, track)
    assert np.flatnonzero(out[:, W]).tolist() == [5, 12, 13, 28]
    assert np.flatnonzero(out[:, E]).tolist() == [20, 28]
    assert out.sum() == 6
    assert np.array_equal(spikes(1000 * X, instant, track, unit=1000.0), out)
    assert not spikes(truth, instant, track).any()
    flicker = truth.copy()
    flicker[1::2, W] += [0.15, 0.0, 0.0]
    assert not spikes(flicker, instant, track).any()


def test_an_elbow_three_views_put_elsewhere_for_one_instant_is_refused_and_filled():
    """At one instant of each person, three of five views report the right elbow at one point
    40 cm off, and a fourth has none: the triangulation takes it, and only one view disputes it.
    Left in, it was 122-133 mm off there, and the smoothing carried it to the instants either
    side (84-93 mm). Refused as off its track and back, it is filled from its track and the view
    that sees it: within a few centimetres at every instant around it."""
    sim = simulate_rig(RigSimConfig(cameras=5, people=2, frames=90, distortion=0.0, seed=4))
    cameras = sim.calibration.cameras
    elbow = INDEX["right_elbow"]
    rng = np.random.default_rng(0)
    spiked = ((0, 40), (1, 60))
    for g, t in spiked:
        offset = rng.normal(size=3)
        offset *= 0.4 / np.linalg.norm(offset)
        for v in range(1, 5):
            rows = np.flatnonzero((sim.person == g) & (sim.frame == t) & (sim.camera == v))
            if v == 4:
                sim.keypoints[rows, elbow] = 0.0
                continue
            uv, _ = project_views(cameras.subset([v]), sim.poses3d[t, g, elbow] + offset)
            sim.keypoints[rows, elbow, :2] = uv[0]
            sim.keypoints[rows, elbow, 2] = np.maximum(sim.keypoints[rows, elbow, 2], 0.5)
    config = rig_config()
    prior = completion_prior(config)
    det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
    persons = reconstruct_instants(cameras, det, instants_config(config), prior)
    _, persons, X, flags = track_and_complete(persons, RigOptions(frame_rate=30.0), prior, config, det, cameras)
    for g, t0 in spiked:
        errors = []
        for t in range(t0 - 4, t0 + 5):
            rows = np.flatnonzero(persons.instant == t)
            for p, gg in match_persons(X[rows], sim.poses3d[t], 0.5):
                if gg == g:
                    errors.append(np.linalg.norm(X[rows[p], elbow] - sim.poses3d[t, g, elbow]))
                    if t == t0:
                        assert flags[rows[p], elbow] != OBSERVED
        assert len(errors) == 9 and max(errors) < 0.03, (g, np.round(errors, 3))

