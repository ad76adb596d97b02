"""Grouping 2D poses into persons: the paper's greedy Algorithm 1 (and, later, baselines).

Every method takes an affinity matrix and returns groups: lists of pose indices, at most one
pose per view each.
"""
from mvm.core.matching.greedy import greedy_groups

__all__ = ["greedy_groups"]
