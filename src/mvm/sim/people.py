"""Frozen people of a simulated scene: the reference standing body, placement on the floor
(apart, facing the camera's tour, with postures drawn from the pose bank) and their clothes
(appearance descriptors). World frame: metres, z up, floor at z = 0."""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)

#: A standing adult in the pose bank's frame (metres, z up, feet on z = 0, facing +y), COCO order.
STANDING = np.array([
    [0, 0.10, 1.62], [-0.03, 0.08, 1.66], [0.03, 0.08, 1.66], [-0.07, 0.0, 1.64], [0.07, 0.0, 1.64],
    [-0.18, 0, 1.42], [0.18, 0, 1.42], [-0.22, 0.02, 1.13], [0.22, 0.02, 1.13], [-0.24, 0.08, 0.88],
    [0.24, 0.08, 0.88], [-0.10, 0, 0.95], [0.10, 0, 0.95], [-0.11, 0.02, 0.52], [0.11, 0.02, 0.52],
    [-0.11, 0, 0.08], [0.11, 0, 0.08]])
STANDING.flags.writeable = False

#: Postures a simulated person can take (the pose bank's labels).
POSTURES: tuple[str, ...] = ("standing", "sitting", "crouching")


def _disc_positions(config, rng: np.random.Generator, extra: np.random.Generator,
                    tangent: np.ndarray) -> np.ndarray:
    """Pelvis positions ``(G, 2)`` in the crowd's disc, ``min_separation`` apart (and each
    within ``max_separation`` of an earlier person when that is set), except that
    the last ``close_pairs`` people each stand ``close_distance`` beside an earlier person
    (side by side as seen from the tour, whose direction along the arc is ``tangent: (2,)``)."""
    G = config.people
    pairs = min(config.close_pairs, G // 2)
    positions: list[np.ndarray] = []
    tries = 0
    while len(positions) < G - pairs:
        tries += 1
        if tries > 20000:
            spacing = f"{config.min_separation}" + (f"-{config.max_separation}" if config.max_separation else "")
            raise ValueError(f"cannot place {config.people} people {spacing} m apart "
                             f"in a disc of radius {config.crowd_radius} m")
        r = config.crowd_radius * np.sqrt(rng.uniform())
        a = rng.uniform(0, 2 * np.pi)
        p = np.array([r * np.cos(a), r * np.sin(a)])
        gaps = [np.linalg.norm(p - q) for q in positions]
        if all(d >= config.min_separation for d in gaps) and (
                config.max_separation is None or not gaps or min(gaps) <= config.max_separation):
            positions.append(p)
    for k in range(pairs):
        for _ in range(2000):
            anchor = positions[int(extra.integers(G - pairs))]
            turn = extra.normal(0, np.radians(20))
            c, s = np.cos(turn), np.sin(turn)
            direction = np.array([c * tangent[0] - s * tangent[1], s * tangent[0] + c * tangent[1]])
            p = anchor + config.close_distance * direction * extra.choice([-1.0, 1.0])
            if all(np.linalg.norm(p - q) >= 0.95 * config.close_distance for q in positions):
                positions.append(p)
                break
        else:
            raise ValueError(f"cannot place close pair {k + 1}: the crowd is too dense")
    return np.array(positions)


def _choose_postures(config, extra: np.random.Generator, labels: np.ndarray | None) -> list[np.ndarray] | None:
    """For every person, the bank indices it may take its pose from (None: the whole bank)."""
    if config.postures is None or labels is None:
        return None
    mix = np.asarray(config.postures, dtype=float)
    if mix.shape != (3,) or (mix < 0).any() or mix.sum() <= 0:
        raise ValueError(f"postures: expected 3 non-negative fractions, got {config.postures}")
    pools = [np.flatnonzero(labels == name) for name in POSTURES]
    available = np.array([len(pool) > 0 for pool in pools])
    if not (mix * available).any():
        raise ValueError(f"the pose bank has none of the postures {POSTURES} asked for")
    if not available.all():
        log.warning("the pose bank lacks %s poses; using the other postures",
                    ", ".join(np.array(POSTURES)[~available]))
    mix = mix * available
    chosen = extra.choice(3, size=config.people, p=mix / mix.sum())
    return [pools[c] for c in chosen]


def place_people(config, rng: np.random.Generator, bank_poses: np.ndarray,
                 toward: np.ndarray, bank_labels: np.ndarray | None = None,
                 extra: np.random.Generator | None = None) -> tuple[np.ndarray, tuple[str, ...]]:
    """Place ``config.people`` bank poses on the floor, apart, facing roughly ``toward: (2,)``.

    ``config`` is a :class:`mvm.sim.simulate.SimConfig`; ``bank_poses: (B, 17, 3)`` in the
    bank frame (pelvis at xy = 0, feet at z = 0, facing +y), ``bank_labels: (B,)`` their
    postures -> ``(G, 17, 3)`` world poses and their ``G`` labels. Bodies keep
    ``body_clearance`` apart: a person that would touch another is turned.
    """
    extra = np.random.default_rng([config.seed, 1]) if extra is None else extra
    heading = np.arctan2(toward[1], toward[0])
    tangent = np.array([-np.sin(heading), np.cos(heading)])
    positions = _disc_positions(config, rng, extra, tangent)
    pools = _choose_postures(config, extra, bank_labels)
    poses, labels = [], []
    for g, p in enumerate(positions):
        index = rng.integers(len(bank_poses))
        if pools is not None:
            index = pools[g][extra.integers(len(pools[g]))]
        pose = bank_poses[index] * rng.uniform(*config.size_range)
        facing = np.arctan2(*(toward - p)[::-1]) - np.pi / 2 + rng.normal(0, np.radians(40))
        for _attempt in range(50):
            c, s = np.cos(facing), np.sin(facing)
            Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
            placed = pose @ Rz.T + np.array([p[0], p[1], 0.0])
            if not poses or _clearance(placed, np.array(poses)) >= config.body_clearance:
                break
            facing = extra.uniform(0, 2 * np.pi)
        else:
            log.debug("person %d touches a neighbour after 50 turns", g)
        poses.append(placed)
        labels.append(str(bank_labels[index]) if bank_labels is not None else "")
    return np.array(poses), tuple(labels) if bank_labels is not None else ()


def _clearance(pose: np.ndarray, others: np.ndarray) -> float:
    """Smallest horizontal distance between a joint of ``pose: (17, 3)`` and one of
    ``others: (G, 17, 3)`` at overlapping heights (within 0.3 m)."""
    d = np.linalg.norm(pose[None, :, None, :2] - others[:, None, :, :2], axis=-1)       # (G, 17, 17)
    level = np.abs(pose[None, :, None, 2] - others[:, None, :, 2]) < 0.3
    return float(np.where(level, d, np.inf).min())


def clothes(config, rng: np.random.Generator, extra: np.random.Generator) -> np.ndarray:
    """Clothes of every person ``(G, D)``: random colours, with ``lookalikes`` people copying
    another's clothes up to a small difference, or all alike with ``identical_clothes``."""
    dim = max(config.appearance_dim, 1)
    base = rng.uniform(0, 1, (config.people, dim))
    if config.identical_clothes:
        base[:] = base[0]
    elif config.lookalikes and config.people > 1:
        for g in range(1, min(config.lookalikes, config.people - 1) + 1):
            twin = config.people - g
            base[twin] = np.clip(base[int(extra.integers(twin))] + extra.normal(0, 0.03, dim), 0, 1)
    return base
