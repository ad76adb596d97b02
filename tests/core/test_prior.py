"""The GMM pose prior: canonical frame, marginal likelihoods, whitening, and the shipped fit."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import multivariate_normal

from mvm.core.config import Config
from mvm.core.keypoints import INDEX, LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER
from mvm.core.posebank import load_pose_bank
from mvm.core.prior import DIM, PosePrior, body_frame, canonicalize, load_prior, shipped_prior
from mvm.errors import InputError

# A standing person (metres, z up, facing +y: the left side at -x).
STANDING = np.array([
    [0, 0.10, 1.62], [-0.03, 0.08, 1.66], [0.03, 0.08, 1.66], [-0.07, 0.0, 1.64], [0.07, 0.0, 1.64],
    [-0.18, 0, 1.42], [0.18, 0, 1.42], [-0.22, 0.02, 1.13], [0.22, 0.02, 1.13], [-0.24, 0.08, 0.88],
    [0.24, 0.08, 0.88], [-0.10, 0, 0.92], [0.10, 0, 0.92], [-0.11, 0.02, 0.50], [0.11, 0.02, 0.50],
    [-0.11, 0, 0.0], [0.11, 0, 0.0]])


@pytest.fixture(scope="module")
def shipped() -> PosePrior:
    return PosePrior.load()


@pytest.fixture(scope="module")
def real_poses() -> np.ndarray:
    bank = load_pose_bank()
    rng = np.random.default_rng(0)
    complete = np.flatnonzero(bank.complete)
    return bank.poses[rng.choice(complete, 400, replace=False)].astype(float)


def _tiny_mixture(rng: np.random.Generator, components: int = 3) -> PosePrior:
    weights = rng.uniform(0.5, 1.5, components)
    means = rng.normal(0, 0.5, (components, DIM))
    a = rng.normal(0, 0.3, (components, DIM, DIM))
    covariances = a @ np.swapaxes(a, 1, 2) / DIM + 0.05 * np.eye(DIM)
    return PosePrior(weights / weights.sum(), means, covariances)


def _direct_nll(prior: PosePrior, x: np.ndarray) -> float:
    """-log Σ w N(x_obs) with scipy, ``x: (17, 3)`` with NaN joints."""
    observed = np.repeat(~np.isnan(x).any(axis=1), 3)
    density = sum(w * multivariate_normal(m[observed], c[np.ix_(observed, observed)]).pdf(x.reshape(-1)[observed])
                  for w, m, c in zip(prior.weights, prior.means, prior.covariances))
    return -np.log(density)


# --- canonicalize ------------------------------------------------------------------------------

@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=st.floats(0.01, 100.0), shift=st.floats(-1000, 1000))
def test_canonicalize_ignores_rotation_translation_and_scale(seed, scale, shift):
    rng = np.random.default_rng(seed)
    pose = STANDING + rng.normal(0, 0.05, STANDING.shape)
    rotation = Rotation.random(random_state=seed % 2**32).as_matrix()
    moved = scale * pose @ rotation.T + shift * rng.normal(size=3)
    np.testing.assert_allclose(canonicalize(moved), canonicalize(pose), atol=1e-9)


def test_canonical_frame_is_the_documented_one():
    rng = np.random.default_rng(1)
    poses = STANDING + rng.normal(0, 0.05, (20, 17, 3))
    c = canonicalize(poses)
    lh, rh, ls, rs = (c[:, j] for j in (LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER))
    np.testing.assert_allclose(lh + rh, 0.0, atol=1e-12)                    # pelvis at the origin
    np.testing.assert_allclose(lh[:, 1:], 0.0, atol=1e-12)                  # hips on the x axis
    assert np.all(lh[:, 0] > 0)                                             # x: right hip -> left hip
    np.testing.assert_allclose((ls + rs)[:, 1], 0.0, atol=1e-12)           # mid-shoulders in the x-z plane
    assert np.all((ls + rs)[:, 2] > 0)                                      # z towards the shoulders
    torso = 0.5 * (np.linalg.norm(ls - lh, axis=-1) + np.linalg.norm(rs - rh, axis=-1))
    np.testing.assert_allclose(torso, 1.0, atol=1e-12)                      # unit torso
    # y = z × x points to the back: the nose of a person facing +y has negative y
    assert canonicalize(STANDING)[INDEX["nose"], 1] < 0
    # the standing pose, by hand: hips at ±0.10 m, torso sqrt(0.08² + 0.50²) m
    np.testing.assert_allclose(canonicalize(STANDING)[LEFT_HIP], [0.10 / np.hypot(0.08, 0.50), 0, 0], atol=1e-12)


def test_canonicalize_missing_joints():
    pose = np.stack([STANDING] * 3)
    pose[0, INDEX["left_knee"]] = np.nan
    pose[1, RIGHT_HIP] = np.nan
    pose[2, LEFT_SHOULDER, 0] = np.nan
    c = canonicalize(pose)
    assert np.isnan(c[0, INDEX["left_knee"]]).all() and np.isfinite(np.delete(c[0], INDEX["left_knee"], 0)).all()
    np.testing.assert_allclose(np.delete(c[0], INDEX["left_knee"], 0),
                               np.delete(canonicalize(STANDING), INDEX["left_knee"], 0))
    assert np.isnan(c[1:]).all()
    degenerate = STANDING.copy()
    degenerate[RIGHT_HIP] = degenerate[LEFT_HIP]
    assert np.isnan(canonicalize(degenerate)).all()
    with pytest.raises(ValueError, match=r"\(\.\.\., 17, 3\)"):
        canonicalize(np.zeros((5, 3)))


# --- the mixture math, against scipy -------------------------------------------------------------

def test_nll_matches_scipy_including_marginals():
    rng = np.random.default_rng(7)
    prior = _tiny_mixture(rng)
    x = rng.normal(0, 0.6, (6, 17, 3))
    x[1, [3, 9]] = np.nan                       # two joints missing
    x[2, :10] = np.nan                          # most joints missing
    x[3, 4, 2] = np.nan                         # one coordinate missing: the joint is missing
    x[4] = np.nan                               # nothing observed
    nll = prior.nll(x)
    assert np.isnan(nll[4])
    for p in (0, 1, 2, 3, 5):
        expected = _direct_nll(prior, np.where(np.isnan(x[p]).any(axis=1, keepdims=True), np.nan, x[p]))
        np.testing.assert_allclose(nll[p], expected, rtol=1e-9, atol=1e-9)


def test_log_densities_of_a_mixed_batch_are_each_poses_own():
    """Poses with different missing joints in one batch: every pose and component is its
    marginal's scipy log density plus the log weight."""
    rng = np.random.default_rng(10)
    prior = _tiny_mixture(rng, components=3)
    x = rng.normal(0, 0.6, (5, 17, 3))
    x[1, [3, 9]] = np.nan
    x[3, [3, 9]] = np.nan
    x[2, :10] = np.nan
    out = prior.log_weighted_densities(x)
    for p in range(len(x)):
        coords = ~np.isnan(x[p].reshape(-1))
        values = x[p].reshape(-1)[coords]
        expected = [np.log(w) + multivariate_normal(m[coords], c[np.ix_(coords, coords)]).logpdf(values)
                    for w, m, c in zip(prior.weights, prior.means, prior.covariances)]
        np.testing.assert_allclose(out[p], expected, rtol=1e-9)


def test_best_component_is_the_argmax():
    rng = np.random.default_rng(8)
    prior = _tiny_mixture(rng, components=4)
    # poses drawn near each component's mean belong to it
    x = prior.means.reshape(4, 17, 3) + rng.normal(0, 0.01, (4, 17, 3))
    np.testing.assert_array_equal(prior.best_component(x), [0, 1, 2, 3])
    x[2, :6] = np.nan
    direct = [np.argmax([w * multivariate_normal(m[18:], c[18:, 18:]).pdf(x[2].reshape(-1)[18:])
                         for w, m, c in zip(prior.weights, prior.means, prior.covariances)])]
    assert prior.best_component(x[2:3]).tolist() == direct
    assert prior.best_component(np.full((1, 17, 3), np.nan)).tolist() == [-1]


def test_whitening_gives_the_negative_log_density():
    rng = np.random.default_rng(9)
    prior = _tiny_mixture(rng)
    for present in (np.ones(17, bool), rng.random(17) < 0.5):
        present[0] = True
        observed = np.repeat(present, 3)
        for component in range(prior.components):
            mean, w, c = prior.whitening(present, component)
            assert mean.shape == (3 * present.sum(),) and w.shape == (len(mean), len(mean))
            for _ in range(3):
                x = rng.normal(0, 0.6, len(mean))
                r = w @ (x - mean)
                expected = -np.log(prior.weights[component]) - multivariate_normal(
                    prior.means[component, observed],
                    prior.covariances[component][np.ix_(observed, observed)]).logpdf(x)
                assert abs(0.5 * r @ r + c - expected) < 1e-8
    # cached: the same arrays come back, read-only
    first = prior.whitening(present, 1)
    assert prior.whitening(present.copy(), 1)[1] is first[1] and not first[1].flags.writeable
    with pytest.raises(ValueError, match="no joint"):
        prior.whitening(np.zeros(17, bool), 0)
    with pytest.raises(ValueError, match="component"):
        prior.whitening(present, 3)


def test_prior_checks_its_parameters(tmp_path):
    with pytest.raises(ValueError, match="sum to 1"):
        PosePrior(np.array([0.5, 0.6]), np.zeros((2, DIM)), np.stack([np.eye(DIM)] * 2))
    with pytest.raises(ValueError, match="expected weights"):
        PosePrior(np.array([1.0]), np.zeros((1, 50)), np.eye(DIM)[None])
    np.savez(tmp_path / "p.npz", weights=np.array([1.0]), means=np.zeros((1, DIM)))
    with pytest.raises(InputError, match="covariances"):
        PosePrior.load(tmp_path / "p.npz")


# --- the shipped prior ---------------------------------------------------------------------------

def test_shipped_prior_is_finite_on_every_bank_pose(shipped):
    assert shipped.components == 8
    bank = load_pose_bank()
    nll = shipped.nll(canonicalize(bank.poses.astype(float)))
    assert np.isfinite(nll).all()
    # and on a pose with only the torso left
    torso = np.full((1, 17, 3), np.nan)
    torso[0, [LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER, RIGHT_SHOULDER]] = STANDING[[LEFT_HIP, RIGHT_HIP, LEFT_SHOULDER,
                                                                              RIGHT_SHOULDER]]
    assert np.isfinite(shipped.nll(canonicalize(torso))).all()


def _scrambled(poses: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Impossible versions: a knee or an elbow bent backwards past the joint's limit,
    or a limb's end swapped with another limb's."""
    out = poses.copy()
    limbs = [(11, 13, 15), (12, 14, 16), (5, 7, 9), (6, 8, 10)]
    for p in range(len(out)):
        root, middle, end = limbs[rng.integers(4)]
        if rng.random() < 0.5:
            # reflect the middle joint through the root: the thigh (or upper arm) points the other way
            out[p, middle] = 2 * out[p, root] - poses[p, middle]
            out[p, end] = out[p, middle] + (poses[p, end] - poses[p, middle])
        else:
            a, b = rng.choice([9, 10, 15, 16], 2, replace=False)      # wrists and ankles trade places
            out[p, [a, b]] = poses[p, [b, a]]
    return out


def test_real_poses_beat_scrambled_ones(shipped, real_poses):
    rng = np.random.default_rng(4)
    real = shipped.nll(canonicalize(real_poses))
    fake = shipped.nll(canonicalize(_scrambled(real_poses, rng)))
    assert np.mean(real < fake) > 0.95, np.mean(real < fake)


def test_real_poses_beat_random_limb_directions(shipped, real_poses):
    """Every limb segment turned to a random direction, lengths kept."""
    rng = np.random.default_rng(5)
    fake = real_poses.copy()
    for parent, child in [(5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16)]:
        length = np.linalg.norm(real_poses[:, child] - real_poses[:, parent], axis=-1, keepdims=True)
        direction = rng.normal(size=(len(fake), 3))
        fake[:, child] = fake[:, parent] + length * direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    real = shipped.nll(canonicalize(real_poses))
    assert np.mean(real < shipped.nll(canonicalize(fake))) > 0.95


def test_body_frame_is_a_rotation_that_gives_the_canonical_pose():
    rng = np.random.default_rng(2)
    poses = STANDING + rng.normal(0, 0.05, (10, 17, 3))
    rotation, centre, scale = body_frame(poses)
    np.testing.assert_allclose(rotation @ np.swapaxes(rotation, -1, -2), np.broadcast_to(np.eye(3), (10, 3, 3)),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rotation), 1.0)
    manual = np.einsum("pij,pkj->pki", rotation, poses - centre[:, None]) / scale[:, None, None]
    np.testing.assert_allclose(canonicalize(poses), manual, atol=1e-12)


def test_load_prior_has_one_rule_for_every_driver():
    given = _tiny_mixture(np.random.default_rng(0))
    assert load_prior(Config(), given) is given                                 # a given prior wins
    assert load_prior(Config(refine=False)) is None                             # not used: not read
    assert load_prior(Config(prior_weight=0.0)) is None
    shipped = load_prior(Config())
    assert isinstance(shipped, PosePrior) and shipped.components == 8           # the paper's 8 components
    assert load_prior(Config()) is shipped is shipped_prior()                   # read once per process


# --- numpy in place of scipy.linalg / scipy.special ----------------------------------------------

def test_logsumexp_and_responsibilities_match_scipy():
    """The stable logsumexp against scipy's, including -inf entries and huge magnitudes; the
    posterior of the components is the softmax of the weighted densities."""
    from scipy.special import logsumexp as scipy_logsumexp
    from scipy.special import softmax

    from mvm.core.prior import logsumexp

    a = np.array([[0.0, 1.0, 2.0], [-1e4, -1e4 + 1, -np.inf], [-np.inf, -np.inf, -np.inf], [800.0, 799.0, 0.0]])
    np.testing.assert_allclose(logsumexp(a, axis=1), scipy_logsumexp(a, axis=1), rtol=1e-14)
    np.testing.assert_allclose(logsumexp(a.T, axis=0), scipy_logsumexp(a, axis=1), rtol=1e-14)
    prior = _tiny_mixture(np.random.default_rng(3))
    x = np.random.default_rng(4).normal(0, 0.5, (5, 17, 3))
    x[1, 3:9] = np.nan
    np.testing.assert_allclose(prior.responsibilities(x), softmax(prior.log_weighted_densities(x), axis=1),
                               rtol=1e-12, atol=1e-300)


def test_whitening_is_the_inverse_lower_cholesky_factor():
    """``W`` is lower triangular with ``W Σ_obs Wᵀ = I`` (scipy's triangular solve gave the same)."""
    from scipy.linalg import cholesky, solve_triangular

    prior = _tiny_mixture(np.random.default_rng(5))
    present = np.ones(17, bool)
    present[[2, 9]] = False
    _, W, _ = prior.whitening(present, 1)
    coords = np.repeat(present, 3)
    cov = prior.covariances[1][np.ix_(coords, coords)]
    assert np.array_equal(W, np.tril(W))
    np.testing.assert_allclose(W @ cov @ W.T, np.eye(len(W)), atol=1e-10)
    expected = solve_triangular(cholesky(cov, lower=True), np.eye(len(W)), lower=True)
    np.testing.assert_allclose(W, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())
