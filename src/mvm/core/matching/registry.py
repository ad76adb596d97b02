"""One interface for every grouping method and every affinity of the paper's Tables 1 and 2.

A *matcher* is ``fn(A, score, view, config, baseline) -> groups``: affinities ``A: (N, N)``
in [0, 0.5] (NaN: undefined), pose confidences and views ``(N,)``, the reconstruction
:class:`~mvm.core.config.Config` (τ, minimum score, minimum group size) and a
:class:`~mvm.core.matching.baselines.BaselineConfig`. An *affinity* is ``fn(scene, config) -> A``.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mvm.core.affinity import affinity, mse_distance, pose_affinity
from mvm.core.config import Config
from mvm.core.matching.baselines import BaselineConfig, dong_groups, hungarian_groups, shortest_path_groups
from mvm.core.matching.greedy import greedy_groups
from mvm.core.scene import Scene

Matcher = Callable[[np.ndarray, np.ndarray, np.ndarray, Config, BaselineConfig], list]


def _greedy(A, score, view, config: Config, baseline: BaselineConfig):
    return greedy_groups(A, score, view, config.tau, config.min_pose_score, config.min_group_size)


def _hungarian(A, score, view, config: Config, baseline: BaselineConfig):
    return hungarian_groups(A, score, view, baseline.link_affinity, baseline.max_gap_frames,
                            config.min_pose_score, config.min_group_size)


def _shortest_path(A, score, view, config: Config, baseline: BaselineConfig):
    return shortest_path_groups(A, score, view, baseline.link_affinity, baseline.max_gap_frames,
                                config.min_pose_score, config.min_group_size)


def _dong(A, score, view, config: Config, baseline: BaselineConfig):
    return dong_groups(A, score, view, baseline, config.min_pose_score, config.min_group_size)


#: Grouping methods by name: the paper's greedy Algorithm 1 ('mvm') and its baselines.
MATCHERS: dict[str, Matcher] = {
    "mvm": _greedy,
    "hungarian": _hungarian,
    "shortest_path": _shortest_path,
    "dong": _dong,
}


def _mse(scene: Scene, config: Config) -> np.ndarray:
    poses = scene.poses
    D = mse_distance(poses.keypoints, poses.view, config.keypoint_threshold, scene.cameras.focal,
                     config.distance_scale, config.min_common_keypoints)
    return affinity(D, config.gamma)


def _geometric(scene: Scene, config: Config) -> np.ndarray:
    return pose_affinity(scene.cameras, scene.poses, config, appearance=False)


def _geometric_appearance(scene: Scene, config: Config) -> np.ndarray:
    return pose_affinity(scene.cameras, scene.poses, config)


#: Affinities of Table 2: 2D MSE, the epipolar distance D (Eq. 2), and D with appearance (Eq. 1).
AFFINITIES: dict[str, Callable[[Scene, Config], np.ndarray]] = {
    "mse": _mse,
    "geo": _geometric,
    "geo+app": _geometric_appearance,
}


def _lookup(table: dict, name: str, kind: str):
    if name not in table:
        raise ValueError(f"unknown {kind} {name!r}; known: {', '.join(table)}")
    return table[name]


def get_matcher(name: str) -> Matcher:
    """The matcher called ``name`` (one of :data:`MATCHERS`).

    >>> get_matcher("mvm") is MATCHERS["mvm"]
    True
    >>> get_matcher("kmeans")
    Traceback (most recent call last):
    ...
    ValueError: unknown matching method 'kmeans'; known: ...
    """
    return _lookup(MATCHERS, name, "matching method")


def affinity_matrix(scene: Scene, config: Config, kind: str = "geo+app") -> np.ndarray:
    """``A: (N, N)`` of ``scene``'s poses with the affinity ``kind`` (one of :data:`AFFINITIES`)."""
    return _lookup(AFFINITIES, kind, "affinity")(scene, config)


def match_with(scene: Scene, config: Config, method: str = "mvm", kind: str = "geo+app",
               baseline: BaselineConfig | None = None) -> list[np.ndarray]:
    """Group ``scene``'s poses with ``method`` on the affinity ``kind``: pose-index arrays."""
    matcher = get_matcher(method)
    A = affinity_matrix(scene, config, kind)
    return matcher(A, scene.poses.score, scene.poses.view, config, baseline or BaselineConfig())
