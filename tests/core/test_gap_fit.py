"""A joint through a gap (mvm.core.gap_fit): the motion, the bone's sphere and the rays of the
views that still see it, against trajectories the tests construct."""
import numpy as np
import pytest

from mvm.core.gap_fit import fit_gaps, second_differences

L = 0.25                                     # the bone, metres
PERIOD = 40                                  # of a swing, instants


def circle(t: np.ndarray) -> np.ndarray:
    """A joint swinging back and forth about its parent at the bone's length (1.2 radians each
    way), in a plane tilted out of every axis plane."""
    a = 1.2 * np.sin(2 * np.pi * t / PERIOD)
    return L * np.stack([np.cos(a), np.sin(a) * 0.8, np.sin(a) * 0.6], -1)


def gap(n: int, start: int = 10):
    """The known offsets on either side of a gap of ``n`` instants, and the truth inside."""
    t = np.arange(start - 2, start + n + 2, dtype=float)
    r = circle(t)
    return r[None, :2], r[None, -2:], r[2:-2]


def camera_rays(truth: np.ndarray, centre: np.ndarray, noise: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """``(1, n, 1, 3)`` rays from ``centre`` through the truth moved by ``noise`` across the ray."""
    target = truth + rng.normal(0, noise, truth.shape)
    d = target - centre
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(centre, truth.shape)[None, :, None].copy(), d[None, :, None]


def no_prior(n):
    return np.full((1, n, 3), np.nan)


def test_second_differences_by_hand():
    D = second_differences(1)
    assert D.tolist() == [[1, -2, 1, 0, 0], [0, 1, -2, 1, 0], [0, 0, 1, -2, 1]]


def test_uniform_motion_is_continued_exactly():
    """No bone, no rays: a joint moving at constant velocity is filled on its line."""
    t = np.arange(16, dtype=float)
    line = np.stack([0.01 * t, -0.02 * t + 0.3, 0.005 * t], -1)
    r, std, _ = fit_gaps(line[None, :2], line[None, -2:], np.array([np.nan]), np.array([0.01]), 0.01,
                         no_prior(12))
    assert np.abs(r[0] - line[2:-2]).max() < 1e-9
    assert (std[0, 1:6] > std[0, :5]).all() and (std[0, 6:] < std[0, 5:-1]).all()   # widest mid-gap


def test_the_bone_keeps_a_turning_joint_on_its_sphere():
    """Interpolation cuts the arc's chord; held at the bone's length the fill follows the arc."""
    before, after, truth = gap(20)
    args = (before, after)
    free, _, _ = fit_gaps(*args, np.array([np.nan]), np.array([0.01]), 0.01, no_prior(20))
    held, _, _ = fit_gaps(*args, np.array([L]), np.array([0.01]), 0.005, no_prior(20))
    assert np.linalg.norm(free[0], axis=-1).min() < 0.9 * L
    assert np.abs(np.linalg.norm(held[0], axis=-1) - L).max() < 0.01
    assert np.linalg.norm(held[0] - truth, axis=-1).mean() < 0.5 * np.linalg.norm(free[0] - truth, axis=-1).mean()


def test_one_view_fixes_the_depth():
    """One view's noisy ray and the bone's sphere put the joint within the ray's noise of the
    truth, where the motion alone cannot follow a turn of the arm; the posterior narrows."""
    rng = np.random.default_rng(0)
    before, after, truth = gap(30)
    o, d = camera_rays(truth, np.array([3.0, -2.0, 1.0]), 0.01, rng)
    sigma = np.array([0.004])
    blind, std_blind, _ = fit_gaps(before, after, np.array([L]), sigma, 0.005, no_prior(30))
    seen, std_seen, weight = fit_gaps(before, after, np.array([L]), sigma, 0.005, no_prior(30), np.inf,
                                      o, d, 0.01, 0.25)
    error = np.linalg.norm(seen[0] - truth, axis=-1)
    assert error.mean() < 0.02 and error.mean() < 0.5 * np.linalg.norm(blind[0] - truth, axis=-1).mean()
    assert (std_seen < std_blind).all() and (weight > 0.5).all()


def test_the_ray_s_other_meeting_with_the_sphere_is_found():
    """The motion alone would put the joint at the far meeting of the ray with the sphere: the
    second start (the mirrored one) and the objective pick the near one, the truth."""
    n = 12
    t = np.arange(n + 4, dtype=float)
    # the joint swings from +x through +y to -x in a horizontal plane, but leaves +x and
    # reaches -x moving towards -y: the smooth guess goes round through -y
    s = t / (n + 3)
    a = np.pi * s - 0.7 * np.sin(2 * np.pi * s)
    truth_all = L * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1)
    before, after, truth = truth_all[None, :2], truth_all[None, -2:], truth_all[2:-2]
    centre = np.array([0.0, 5.0, 0.0])                                  # looks along -y: depth is y
    o, d = camera_rays(truth, centre, 0.0, np.random.default_rng(1))
    r, _, _ = fit_gaps(before, after, np.array([L]), np.array([0.03]), 0.005, no_prior(n), np.inf, o, d, 0.01, 0.25)
    error = np.linalg.norm(r[0] - truth, axis=-1)
    assert error.max() < 0.04 and error.mean() < 0.015          # the far side is 0.48 m off mid-gap


def test_a_far_ray_is_refused():
    """A keypoint of someone else (its ray a metre from the joint) weighs nothing."""
    before, after, truth = gap(15)
    o, d = camera_rays(truth + np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 5.0]), 0.0, np.random.default_rng(2))
    args = (before, after, np.array([L]), np.array([0.01]), 0.005, no_prior(15))
    alone, _, _ = fit_gaps(*args)
    r, _, weight = fit_gaps(*args, np.inf, o, d, 0.02, 0.25)
    assert (weight == 0).all() and np.abs(r - alone).max() < 1e-9


def test_a_view_that_reports_another_thing_through_the_gap_is_refused():
    """Two views: one sees the joint, the other reports a point 10 cm off it through the whole
    gap (its rays within the gate of the fill and the rays' Cauchy scale). Tried against the motion where the gap begins
    and ends (``gate_sigmas``), the second view is refused whole and the fill follows the first;
    without that test it pulls the fill off."""
    rng = np.random.default_rng(3)
    n = 25
    before, after, truth = gap(n)
    o1, d1 = camera_rays(truth, np.array([3.0, -2.0, 1.0]), 0.005, rng)
    o2, d2 = camera_rays(truth + np.array([0.0, 0.06, 0.08]), np.array([-2.0, -3.0, 0.5]), 0.005, rng)
    o, d = np.concatenate([o1, o2], 2), np.concatenate([d1, d2], 2)
    args = (before, after, np.array([L]), np.array([0.004]), 0.005, no_prior(n), np.inf, o, d, 0.02, 0.25)
    plain, _, _ = fit_gaps(*args)
    tried, _, weight = fit_gaps(*args, gate_sigmas=2.0)
    error = np.linalg.norm(tried[0] - truth, axis=-1)
    assert (weight[0, :, 1] == 0).all() and (weight[0, :, 0] > 0.5).mean() > 0.9
    assert error.mean() < 0.02 and error.mean() < 0.6 * np.linalg.norm(plain[0] - truth, axis=-1).mean()


def test_a_gate_that_refuses_every_view_is_widened(monkeypatch):
    """The joint, still before and after a gap of 10 instants, swings 1.2 radians out and back
    through it, faster than the motion's deviation allows: where the gap begins the one view's
    rays lie beyond ``gate_sigmas`` of the motion's guess, and refused whole they left the fill
    to that guess (200 mm off). The gate is widened where it refuses every view: the view is kept
    and the fill follows it."""
    import mvm.core.gap_fit as gap_fit

    n = 10
    t = np.arange(n + 4) - 2.0
    a = np.where((t >= 0) & (t < n), 1.2 * np.sin(np.pi * (t + 1) / (n + 1)), 0.0)
    path = L * np.stack([np.cos(a), np.sin(a) * 0.8, np.sin(a) * 0.6], -1)
    before, after, truth = path[None, :2], path[None, -2:], path[2:-2]
    o, d = camera_rays(truth, np.array([4.0, 0.0, 0.0]), 0.005, np.random.default_rng(4))
    args = (before, after, np.array([L]), np.array([0.02]), 0.005, no_prior(n), np.inf, o, d, 0.01, 0.25)
    r, _, weight = fit_gaps(*args, gate_sigmas=3.0)
    assert (weight > 0).all() and np.linalg.norm(r[0] - truth, axis=-1).mean() < 0.02
    monkeypatch.setattr(gap_fit, "GATE_DOUBLINGS", 0)
    r, _, weight = fit_gaps(*args, gate_sigmas=3.0)
    assert (weight == 0).all() and np.linalg.norm(r[0] - truth, axis=-1).mean() > 0.15


def test_the_prior_weighs_less_where_a_view_kept_by_the_gate_sees_the_joint():
    """A prior 12 cm off along the one view's rays at every instant of a gap (its guess is one
    for the pose, off alike throughout). Where the rays were tried against the motion
    (``gate_sigmas``) and kept, ``prior_where_seen`` scales its weight: at 0 the fill is the fill
    without a prior, at 1 the prior draws it along the rays, and a quarter lies between. Rays not
    so tried keep the prior's full weight."""
    n = 20
    before, after, truth = gap(n)
    o, d = camera_rays(truth, np.array([3.0, -2.0, 1.0]), 0.005, np.random.default_rng(5))
    prior = (truth + 0.12 * d[0, :, 0])[None]
    args = (before, after, np.array([np.nan]), np.array([0.004]), 0.005)
    rays = (o, d, 0.02, 0.25)
    alone, _, _ = fit_gaps(*args, no_prior(n), np.inf, *rays, gate_sigmas=3.0)
    fills = {w: fit_gaps(*args, prior, 0.1, *rays, gate_sigmas=3.0, prior_where_seen=w) for w in (0.0, 0.25, 1.0)}
    assert all((weight > 0).all() for _, _, weight in fills.values())
    assert np.abs(fills[0.0][0] - alone).max() < 1e-6
    pull = {w: np.abs(((r - alone) * d[:, :, 0]).sum(-1)).mean() for w, (r, _, _) in fills.items()}   # along the rays
    assert pull[0.0] < 1e-6 < pull[0.25] < 0.5 * pull[1.0]
    untried, _, _ = fit_gaps(*args, prior, 0.1, *rays, prior_where_seen=0.25)
    assert np.abs(untried - fit_gaps(*args, prior, 0.1, *rays)[0]).max() < 1e-12


def test_the_uncertainty_grows_with_the_gap():
    stds = []
    for n in (10, 20, 40):
        before, after, _ = gap(n)
        _, std, _ = fit_gaps(before, after, np.array([L]), np.array([0.005]), 0.005, no_prior(n))
        stds.append(std.max())
    assert stds[0] < stds[1] < stds[2]


def test_batched_equals_one_by_one():
    rng = np.random.default_rng(3)
    gaps = [gap(8, start=s) for s in (0, 7, 19)]
    before = np.concatenate([g[0] for g in gaps])
    after = np.concatenate([g[1] for g in gaps])
    rays = [camera_rays(g[2], np.array([2.0, 2.0, 1.0]), 0.01, rng) for g in gaps]
    o, d = np.concatenate([r[0] for r in rays]), np.concatenate([r[1] for r in rays])
    sigma = np.array([0.004, 0.006, 0.01])
    together = fit_gaps(before, after, np.full(3, L), sigma, 0.005, None, np.inf, o, d, 0.01, 0.25)
    for i in range(3):
        alone = fit_gaps(before[i:i + 1], after[i:i + 1], np.array([L]), sigma[i:i + 1], 0.005, None, np.inf,
                         o[i:i + 1], d[i:i + 1], 0.01, 0.25)
        for a, b in zip(together, alone):
            np.testing.assert_allclose(a[i:i + 1], b, atol=1e-9)


def test_bad_input_is_named():
    before, after, _ = gap(5)
    with pytest.raises(ValueError, match="before, after"):
        fit_gaps(before[:, :1], after, np.array([L]), np.array([0.01]), 0.01, no_prior(5))
    with pytest.raises(ValueError, match="on one side at least"):
        fit_gaps(np.full_like(before, np.nan), np.full_like(after, np.nan), np.array([L]), np.array([0.01]), 0.01,
                 no_prior(5))
    with pytest.raises(ValueError, match="sigma_acc"):
        fit_gaps(before, after, np.array([L]), np.array([0.0]), 0.01, no_prior(5))
