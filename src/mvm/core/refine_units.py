"""The units the refinement (:mod:`mvm.core.refine`) weighs each person in: its scene's detector
noise relative to the noise the settings are set for (:func:`noise_factor`), and the weight of
its pose prior (:func:`prior_weights`), which follows that noise and how well its views
constrain it (:func:`mvm.core.geometry.view_spread`). Arrays in, arrays out."""
from __future__ import annotations

import numpy as np

from mvm.core.config import Config
from mvm.core.geometry import view_spread

#: The view spread (:func:`mvm.core.geometry.view_spread`) of a person seen from all around,
#: the one ``prior_weight`` is set for: views evenly around a circle (a camera ring, a dome).
ALL_ROUND_SPREAD = 0.5
#: A person of a smaller view spread gets ``prior_weight`` times ``ALL_ROUND_SPREAD / spread``,
#: at most this many times (a hand-held tour's arc of 60°: about 6 times before the bound).
MAX_SPREAD_FACTOR = 5.0


def noise_factor(threshold: np.ndarray, config: Config) -> np.ndarray:
    """``(P,)`` the detector noise of each person's scene (or rig instant) relative to the noise
    the settings are set for: its RANSAC threshold (``threshold: (P,)``,
    :func:`mvm.core.pipeline.block_thresholds`) over ``ransac_threshold``, 1 where the threshold
    is held. The refinement measures residuals in person sizes times this factor, so that its
    robust scale grows with the noise and the prior weighs against the keypoints as the noise's
    variance (as in a Gaussian likelihood).

    >>> noise_factor(np.array([0.06, 0.12, 0.24]), Config()).tolist()
    [0.5, 1.0, 2.0]
    """
    return np.asarray(threshold, dtype=float) / config.ransac_threshold


def spread_factor(spread: np.ndarray) -> np.ndarray:
    """``(P,)`` how many times ``prior_weight`` a person of view spread ``spread: (P,)`` gets:
    1 from :data:`ALL_ROUND_SPREAD` up, ``ALL_ROUND_SPREAD / spread`` below (at most
    :data:`MAX_SPREAD_FACTOR`), 1 where the spread is unknown (NaN).

    >>> spread_factor(np.array([0.6, 0.5, 0.25, 0.0, np.nan])).tolist()
    [1.0, 1.0, 2.0, 5.0, 1.0]
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = ALL_ROUND_SPREAD / np.asarray(spread, dtype=float)
    return np.where(np.isnan(factor), 1.0, np.clip(factor, 1.0, MAX_SPREAD_FACTOR))


def prior_weights(config: Config, X: np.ndarray, centers: np.ndarray, used: np.ndarray) -> np.ndarray:
    """``(P,)`` the pose prior's weight of each person in the refinement, in its noise units
    (person sizes times its :func:`noise_factor`, squared, per nat; so in person sizes² per nat
    it is this times the noise factor's square): ``prior_weight`` times its :func:`spread_factor`,
    of the view spread of its joints' centroid (``X: (P, J, 3)``, NaN where not reconstructed)
    from the camera centres ``centers: (P, M, 3)`` of its views ``used: (P, M)`` bool (those with
    an inlier keypoint). A person seen from all around has its views' evidence in every
    direction; one on a narrow arc has little evidence of its depth, and the prior holds its shape.

    A person seen from all around a ring, another from a narrow arc: the prior holds the second more.

    >>> ring = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)])
    >>> arc = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 0.2, 8)])
    >>> w = prior_weights(Config(), np.zeros((2, 17, 3)), 5 * np.stack([ring, arc]), np.ones((2, 8), bool))
    >>> bool(w[1] > w[0] == Config().prior_weight)
    True
    """
    finite = np.isfinite(X).all(-1)                                               # (P, J)
    with np.errstate(invalid="ignore"):
        centroid = np.where(finite[..., None], X, 0.0).sum(1) / finite.sum(1)[:, None]
    return config.prior_weight * spread_factor(view_spread(centroid, centers, used))


def noise_threshold(sigma: np.ndarray, config: Config) -> np.ndarray:
    """The RANSAC threshold of noise ``sigma: (B,)`` (person sizes): ``ransac_threshold_sigmas``
    times it, within half to twice ``ransac_threshold``, which a block without a measure (NaN)
    keeps. ``(B,)``.

    >>> config = Config(ransac_threshold=0.1, ransac_threshold_sigmas=3.0)
    >>> noise_threshold(np.array([0.02, 0.01, 0.5, np.nan]), config)
    array([0.06, 0.05, 0.2 , 0.1 ])
    """
    base = config.ransac_threshold
    scaled = np.clip(config.ransac_threshold_sigmas * np.asarray(sigma, dtype=float), base / 2, 2 * base)
    return np.where(np.isfinite(sigma), scaled, base)
