"""Encoder -> decoder round trip: encoding poses and decoding the targets gives them back."""
import numpy as np
import pytest

from mvm.core.camera import project_persons
from mvm.net import encoder
from mvm.net.decoder import decode, normalize_depth
from mvm.net.headmeta import PAF_CONNECTIONS, VIRTUAL_CONNECTIONS, flip_connections
from mvm.sim import people_images as images

SIZE = 256


def _connected(visible: np.ndarray) -> bool:
    """Whether the visible joints of one pose form one component of the PAF graph."""
    joints = set(np.nonzero(visible)[0])
    if not joints:
        return True
    seen, todo = set(), [min(joints)]
    while todo:
        j = todo.pop()
        if j in seen:
            continue
        seen.add(j)
        todo += [b if a == j else a for a, b in PAF_CONNECTIONS if j in (a, b) and {a, b} <= joints]
    return seen == joints


def crowded_scenes(seed: int, n: int, persons: int = 8, min_separation_px: float = 4.0):
    """Scenes of ``persons`` overlapping people; same joints of two people are at least
    ``min_separation_px`` apart (closer ones are ambiguous for any field representation)."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        people, K = images.random_scene(rng, persons, (SIZE, SIZE), distance=(2.0, 4.0))
        kp, dep = project_persons(people, K, np.eye(3), np.zeros(3), (SIZE, SIZE))
        keep = ((kp[:, :, 2] > 0).sum(1) >= 5) & np.array([_connected(k[:, 2] > 0) for k in kp])
        kp, dep = kp[keep], dep[keep]
        xy = np.where(kp[..., 2:] > 0, kp[..., :2], np.nan)
        d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
        d[np.arange(len(kp)), np.arange(len(kp))] = np.inf
        if len(kp) >= 2 and np.nanmin(d) >= min_separation_px:
            out.append((kp, dep))
    return out


def _boxes_overlap(kp: np.ndarray) -> bool:
    lo = np.array([k[k[:, 2] > 0, :2].min(0) for k in kp])
    hi = np.array([k[k[:, 2] > 0, :2].max(0) for k in kp])
    inter = np.minimum(hi[:, None], hi[None]) - np.maximum(lo[:, None], lo[None])
    overlap = (inter > 0).all(-1)
    np.fill_diagonal(overlap, False)
    return overlap.any()


@pytest.mark.parametrize("stride", [8, 16])
def test_round_trip_crowded(stride):
    scenes = crowded_scenes(seed=stride, n=12 if stride == 8 else 6, min_separation_px=4.0 * stride / 8)
    assert sum(_boxes_overlap(kp) for kp, _ in scenes) >= len(scenes) // 2  # really crowded
    for kp, dep in scenes:
        targets = encoder.encode(kp, (SIZE, SIZE), stride, dep)
        poses = decode(encoder.targets_as_fields(targets), stride)
        assert len(poses) == len(kp)
        for i in range(len(kp)):
            vis = kp[i, :, 2] > 0
            err = np.array([np.where(p[vis, 2] > 0, np.linalg.norm(p[vis, :2] - kp[i, vis, :2], axis=-1), np.inf).max()
                            for p in poses.keypoints])
            j = int(np.argmin(err))
            assert err[j] < 1.0, f"person {i}: max keypoint error {err[j]:.2f} px"
            assert ((poses.keypoints[j, :, 2] > 0) == vis).all()
            np.testing.assert_allclose(poses.depth[j, vis], dep[i, vis], rtol=0.01)


def test_targets_shapes_and_ignore_regions():
    kp = np.zeros((1, 17, 3))
    kp[0, :, :2] = np.linspace(20, 80, 17)[:, None]
    kp[0, :, 2] = 2
    kp[0, 9, 2] = 0  # left wrist not annotated
    t = encoder.encode(kp, (100, 100), 8, depths=None)
    H = W = 13
    assert t["pif"].shape == (17, 5, H, W) and t["paf"].shape == (len(PAF_CONNECTIONS), 7, H, W)
    assert t["pdf"].shape == (17, 2, H, W) and t["pdf_group"].shape == (17, H, W)
    assert np.isnan(t["pdf"]).all()  # 2D-only: no depth target anywhere
    assert (t["pdf_group"] == -1).all()
    assert np.isnan(t["pif"][9, 0]).any()  # missing joint: ignored inside the person's box
    assert np.nanmax(t["pif"][9, 0]) == 0
    assert (t["pif"][0, 0] == 1).sum() == 16  # a 4x4 patch of cells points at the nose


def test_empty_image_is_all_background():
    t = encoder.encode(np.zeros((0, 17, 3)), (64, 48), 16)
    assert t["pif"].shape == (17, 5, 3, 4)
    assert (t["pif"][:, 0] == 0).all() and (t["paf"][:, 0] == 0).all()
    assert len(decode(encoder.targets_as_fields(t), 16)) == 0


def test_connections_are_symmetric_and_virtual():
    flip = flip_connections(PAF_CONNECTIONS)
    assert sorted(flip) == list(range(len(PAF_CONNECTIONS)))
    named = dict(zip(PAF_CONNECTIONS, VIRTUAL_CONNECTIONS))
    assert named[(3, 5)] and named[(4, 6)]  # ear-shoulder: virtual
    assert not named[(5, 7)]  # shoulder-elbow: a bone


def test_normalize_depth():
    d = np.array([[2.0, 4.0, 6.0, np.nan]])
    np.testing.assert_allclose(normalize_depth(d), [[0.5, 1.0, 1.5, np.nan]])
