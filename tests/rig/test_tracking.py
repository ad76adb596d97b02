"""Tracks against true identities: an id survives a 10-instant loss, two people crossing close
keep theirs, a person sharing too few joints with a track does not take its id."""
import numpy as np

from mvm.rig.tracking import assign, identity_switches, link_tracks, track_persons

from helpers import STANDING


def _walk(start, velocity, T, noise, rng):
    """``(T, 17, 3)`` a standing pose translated along ``velocity`` (metres per instant)."""
    steps = np.arange(T)[:, None] * np.asarray(velocity, float)
    return STANDING[None] + np.asarray(start, float) + steps[:, None] + rng.normal(0, noise, (T, 17, 3))


def _flatten(people, seen):
    """people: list of (T, 17, 3); seen: list of (T,) bool -> X, instant, truth."""
    X, instant, truth = [], [], []
    for t in range(len(people[0])):
        for g, (pose, ok) in enumerate(zip(people, seen)):
            if ok[t]:
                X.append(pose[t])
                instant.append(t)
                truth.append(g)
    return np.array(X), np.array(instant), np.array(truth)


def test_id_survives_a_10_instant_loss():
    rng = np.random.default_rng(0)
    T = 40
    walker = _walk([0, 0, 0], [0.05, 0, 0], T, 0.01, rng)               # 1.5 m/s at 30 Hz
    other = _walk([0, 3, 0], [-0.03, 0, 0], T, 0.01, rng)
    seen = np.ones(T, bool)
    seen[15:25] = False                                                  # unseen for 10 instants
    X, instant, truth = _flatten([walker, other], [seen, np.ones(T, bool)])
    result = track_persons(X, instant, 0.5, max_gap=10)
    assert identity_switches(result.track, truth, instant) == {"switches": 0, "tracks_per_person": 1.0,
                                                                "persons": 2}
    assert result.tracks == 2 and result.resumed == 1
    # the walker moved 0.55 m while unseen: without its motion the track breaks
    still = track_persons(X, instant, 0.5, max_gap=10, velocity_weight=0.0)
    assert identity_switches(still.track, truth, instant)["tracks_per_person"] > 1


def test_two_people_crossing_close_keep_their_ids():
    rng = np.random.default_rng(1)
    T = 40
    a = _walk([-0.8, 0, 0], [0.04, 0, 0], T, 0.01, rng)
    b = _walk([0.8, 0.2, 0], [-0.04, 0, 0], T, 0.01, rng)                 # 20 cm apart when they cross
    seen_b = np.ones(T, bool)
    seen_b[14:24] = False                                                # hidden behind a while crossing
    seen_a = np.ones(T, bool)
    seen_a[22:24] = False
    X, instant, truth = _flatten([a, b], [seen_a, seen_b])
    order = rng.permutation(len(X))                                      # input order must not matter
    track = link_tracks(X[order], instant[order], 0.5, max_gap=10)
    assert identity_switches(track, truth[order], instant[order])["switches"] == 0
    assert len(np.unique(track)) == 2
    still = link_tracks(X, instant, 0.5, max_gap=10, velocity_weight=0.0)
    assert identity_switches(still, truth, instant)["switches"] > 0    # nearest last pose swaps them


def test_gate_needs_enough_shared_joints():
    """A track known only by its head; a person whose one shared joint (the nose) falls on it but
    whose body is 1.3 m away is another person."""
    head = np.full((17, 3), np.nan)
    head[:5] = STANDING[:5]
    other = STANDING + [1.3, 0, 0]
    other[0] = STANDING[0] + 0.01                                        # a wrong nose, near the track's
    other[1:5] = np.nan
    X = np.stack([head, other])
    instant = np.array([0, 1])
    assert len(np.unique(link_tracks(X, instant, 0.5, max_gap=5))) == 2
    result = track_persons(X, instant, 0.5, max_gap=5, min_joints=1)
    assert len(np.unique(result.track)) == 1                             # a one-joint gate is fooled
    assert track_persons(X, instant, 0.5, max_gap=5).unlinked == 1


def test_identity_switches_counts():
    track = np.array([0, 0, 1, 1, 0, 2])
    truth = np.array([0, 0, 0, 0, 0, -1])
    instant = np.arange(6)
    assert identity_switches(track, truth, instant) == {"switches": 2, "tracks_per_person": 2.0, "persons": 1}


def test_assignment_is_the_hungarian_one_with_or_without_conflicts():
    """The shortcut (every row's cheapest feasible column distinct) and the Hungarian fallback
    give the assignment scipy's gives, on gated random costs of every shape."""
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(3)
    shortcut = conflicts = 0
    for _ in range(400):
        R, C = rng.integers(0, 6, 2)
        cost = rng.uniform(0, 1, (R, C))
        feasible = cost < rng.uniform(0.1, 0.9)
        r, c = linear_sum_assignment(np.where(feasible, cost, 1e12))
        ok = feasible[r, c]
        got = assign(cost, feasible)
        assert {(int(a), int(b)) for a, b in zip(*got)} == {(int(a), int(b)) for a, b in zip(r[ok], c[ok])}
        if not feasible.any():
            continue
        best = np.argmin(np.where(feasible, cost, np.inf), axis=1)[feasible.any(1)]
        distinct = len(np.unique(best)) == len(best)
        shortcut += distinct
        conflicts += not distinct
    assert shortcut > 50 and conflicts > 50                                     # both paths tested



def test_instants_a_track_missed_whole_get_a_row_filled_by_the_completion(tmp_path):
    """A person none of whose keypoints any camera has at instants 20-22 (two others about): the
    track resumes after them, and the completion gives it a row at each, every joint interpolated
    within 3 cm of the truth, no member, no view; written to ``poses3d.jsonl`` and read back so.
    Without completion no row is made."""
    from mvm.core.completion import FLAG_NAMES, INTERPOLATED, OBSERVED
    from mvm.core.config import Config
    from mvm.io.rig_poses3d import read_rig_poses3d
    from mvm.metrics.poses import match_persons
    from mvm.rig.instants import reconstruct_instants, rig_poses
    from mvm.rig.options import RigOptions
    from mvm.rig.reconstruct_rig import (
        completion_prior,
        instants_config,
        poses3d_lines,
        rig_config,
        track_and_complete,
    )
    from mvm.sim.rig_scene import RigSimConfig, simulate_rig

    sim = simulate_rig(RigSimConfig(cameras=5, people=3, frames=40, distortion=0.0, seed=2))
    gone = (sim.person == 0) & np.isin(sim.frame, [20, 21, 22])
    sim.keypoints[gone] = 0.0
    det = rig_poses(sim.keypoints, sim.frame, sim.camera, sim.score)
    cameras = sim.calibration.cameras
    runs = {}
    for complete in (True, False):
        config = rig_config(Config(complete=complete))
        prior = completion_prior(config)
        persons = reconstruct_instants(cameras, det, instants_config(config), prior)
        runs[complete] = track_and_complete(persons, RigOptions(frame_rate=30.0), prior, config, det, cameras)
    tracking, persons, X, flags = runs[True]
    assert len(tracking.track) == len(persons) == len(X)
    assert np.all(np.diff(persons.instant) >= 0)
    for t in (20, 21, 22):
        rows = np.flatnonzero(persons.instant == t)
        pairs = dict((g, rows[p]) for p, g in match_persons(X[rows], sim.poses3d[t], 0.5))
        assert len(rows) == 3 and 0 in pairs
        q = pairs[0]
        assert (flags[q] == INTERPOLATED).all() and (persons.members[q] < 0).all() and not persons.inliers[q].any()
        assert np.linalg.norm(X[q] - sim.poses3d[t, 0], axis=-1).max() < 0.03
        assert (flags[rows[rows != q]] == OBSERVED).mean() > 0.9
        before = tracking.track[(persons.instant == 19) & (tracking.track == tracking.track[q])]
        assert len(before) == 1                                          # the same track either side
    _, plain, _, _ = runs[False]
    assert [int((plain.instant == t).sum()) for t in (19, 20, 21, 22, 23)] == [3, 2, 2, 2, 3]
    frames = np.arange(sim.poses3d.shape[0])
    path = tmp_path / "poses3d.jsonl"
    path.write_bytes(poses3d_lines(frames, persons, X, tracking.track, cameras.names, flags, workers=1))
    back = read_rig_poses3d(path)
    q = pairs[0]
    assert back.flags[q].tolist() == [FLAG_NAMES.index("interpolated")] * 17
    assert (back.members[q] < 0).all() and (back.views[q] == 0).all() and np.isnan(back.reprojection_error_px[q])
