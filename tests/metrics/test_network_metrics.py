"""The network's metrics: PA-MPJPE (3DPW protocol), OKS AP, C_var, the depth error; and the scale calibration."""
import numpy as np
import pytest

from mvm.core.geometry import triangulate_dlt
from mvm.core.keypoints import BONES, MEAN_BONE_LENGTHS_M
from mvm.metrics import network as metrics
from mvm.metrics.poses import pa_mpjpe
from mvm.net.lift import calibrate, lift


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_threedpw_protocol_averages_per_track_then_over_tracks():
    rng = np.random.default_rng(1)
    gt = rng.normal(size=(4, 14, 3))
    pred = gt.copy()
    pred[2, 0] += 1.0      # track (a, 1): errors e and 0 -> mean e/2
    vis = np.ones((4, 14), bool)
    vis[3, :8] = False     # only 6 visible joints: ignored
    pred[3] += 10 * rng.normal(size=(14, 3))
    clip = np.array(["a", "a", "a", "b"])
    track = np.array([0, 1, 1, 0])
    total, per = metrics.threedpw_pa_mpjpe(pred, gt, vis, clip, track)
    e = pa_mpjpe(pred[2:3], gt[2:3])[0]
    assert set(per) == {("a", 0), ("a", 1)}
    assert per[("a", 1)] == pytest.approx(e / 2)
    assert total == pytest.approx((0.0 + e / 2) / 2)
    # a prediction that lacks a joint is not scored (the error is over all 14)
    pred[1, 5] = np.nan
    total, per = metrics.threedpw_pa_mpjpe(pred, gt, vis, clip, track)
    assert per[("a", 1)] == pytest.approx(e) and total == pytest.approx(e / 2)


def test_common14_mapping():
    p = np.arange(17 * 3, dtype=float).reshape(17, 3)
    c = metrics.coco_to_common14(p)
    assert c.shape == (14, 3)
    np.testing.assert_allclose(c[0], p[5])
    np.testing.assert_allclose(c[12], 0.5 * (p[5] + p[6]))
    np.testing.assert_allclose(c[13], p[0])


def _coco(keypoints):
    images = [{"id": 1, "file_name": "a.png", "width": 200, "height": 200}]
    anns = [{"id": i + 1, "image_id": 1, "category_id": 1, "keypoints": k.reshape(-1).tolist(), "iscrowd": 0}
            for i, k in enumerate(keypoints)]
    return {"images": images, "annotations": anns, "categories": [{"id": 1, "name": "person"}]}


def test_oks_ap_perfect_wrong_and_empty():
    rng = np.random.default_rng(2)
    kp = np.concatenate([rng.uniform(20, 180, (2, 17, 2)), np.full((2, 17, 1), 2.0)], -1)
    gt = _coco(kp)
    perfect = [{"image_id": 1, "keypoints": k.reshape(-1).tolist(), "score": 0.9} for k in kp]
    assert metrics.oks_ap(gt, perfect)["AP"] == pytest.approx(1.0)
    wrong = [{"image_id": 1, "keypoints": (k + [[60, 60, 0]]).reshape(-1).tolist(), "score": 0.9} for k in kp]
    assert metrics.oks_ap(gt, wrong)["AP"] == pytest.approx(0.0)
    half = perfect[:1]
    assert 0.4 < metrics.oks_ap(gt, half)["AP"] < 0.6
    assert metrics.oks_ap(gt, [])["AP"] == 0.0


def _cameras(n, rng):
    P = []
    for k in range(n):
        a = 2 * np.pi * k / n
        R = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
        C = np.array([5 * np.sin(a), 0, -5 * np.cos(a)])
        K = np.array([[500, 0, 320], [0, 500, 240], [0, 0, 1.0]])
        P.append(K @ np.concatenate([R, -(R @ C)[:, None]], 1))
    return np.array(P)


def test_c_var_zero_for_exact_and_grows_with_noise():
    rng = np.random.default_rng(3)
    P = _cameras(6, rng)
    X = rng.normal(scale=0.5, size=(2, 17, 3))
    x = np.einsum("vij,pkj->pvki", P, np.concatenate([X, np.ones((2, 17, 1))], -1))
    kp = np.concatenate([x[..., :2] / x[..., 2:], np.full(x.shape[:-1] + (1,), 0.95)], -1)   # (P, V, 17, 3)
    assert metrics.c_var(P, kp, 0.5) == pytest.approx(0.0, abs=1e-12)
    noisy = kp.copy()
    noisy[..., :2] += rng.normal(scale=3.0, size=noisy[..., :2].shape)
    small = metrics.c_var(P, noisy, 0.5)
    noisy2 = kp.copy()
    noisy2[..., :2] += rng.normal(scale=12.0, size=noisy2[..., :2].shape)
    assert 0 < small < metrics.c_var(P, noisy2, 0.5)
    # tau removes the low-confidence outliers
    outlier = kp.copy()
    outlier[:, 0, :, :2] += 80
    outlier[:, 0, :, 2] = 0.6
    assert metrics.c_var(P, outlier, 0.5) > 1e-3
    assert metrics.c_var(P, outlier, 0.9) == pytest.approx(0.0, abs=1e-12)


def test_c_var_is_the_spread_of_the_pairwise_triangulations():
    """Against the definition: every pair of views of a (person, joint) seen by three views or
    more, triangulated on its own, and the mean squared distance to the pairs' mean."""
    rng = np.random.default_rng(5)
    P = _cameras(4, rng)
    X = rng.normal(scale=0.5, size=(3, 17, 3))
    x = np.einsum("vij,pkj->pvki", P, np.concatenate([X, np.ones((3, 17, 1))], -1))
    kp = np.concatenate([x[..., :2] / x[..., 2:] + rng.normal(scale=4.0, size=x[..., :2].shape),
                         rng.uniform(0.0, 1.0, x.shape[:-1] + (1,))], -1)          # (P, V, 17, 3)
    tau = 0.4
    spreads = []
    for p in range(3):
        for j in range(17):
            views = np.flatnonzero(kp[p, :, j, 2] >= tau)
            if len(views) < 3:
                continue
            points = np.array([triangulate_dlt(kp[p, [a, b], j, :2], P[[a, b]])
                               for i, a in enumerate(views) for b in views[i + 1:]])
            spreads.append(((points - points.mean(0)) ** 2).sum(-1).mean())
    assert len(spreads) > 5
    assert metrics.c_var(P, kp, tau) == pytest.approx(np.mean(spreads), rel=1e-9)
    assert np.isnan(metrics.c_var(P, kp, 1.5))                                      # no joint above tau


def test_lift_and_calibrate_recover_a_metric_pose():
    rng = np.random.default_rng(5)
    from mvm.sim.people_images import random_poses
    X = random_poses(rng, 1)[0] * np.array([1, -1, 1]) + np.array([0.2, 1.0, 4.0])   # camera frame, z ≈ 4 m
    bones = np.linalg.norm(X[[a for a, _ in BONES]] - X[[b for _, b in BONES]], axis=-1)
    X *= (MEAN_BONE_LENGTHS_M * bones).sum() / (bones ** 2).sum()                      # a person of mean size
    K = np.array([[400, 0, 160], [0, 400, 120], [0, 0, 1.0]])
    uv = X @ K.T
    kp = np.concatenate([uv[:, :2] / uv[:, 2:], np.ones((17, 1))], -1)[None]
    rel = X[:, 2] / np.median(X[:, 2])
    lifted = lift(kp, rel[None], K)
    metric, s = calibrate(lifted)
    np.testing.assert_allclose(metric[0], X, atol=1e-9)
    assert s[0] == pytest.approx(np.median(X[:, 2]))


def test_relative_depth_error_ignores_scale():
    gt = np.array([[1.0, 1.1, 0.9, np.nan]])
    assert metrics.relative_depth_error(3 * gt, gt)[0] == pytest.approx(0.0)
    assert metrics.relative_depth_error(np.array([[1.0, 1.0, 1.0, 1.0]]), gt)[0] == pytest.approx(0.2 / 3)


def test_oks_ap_equals_pycocotools_on_files(tmp_path):
    """oks_ap against pycocotools' own evaluation of the same ground truth and results files."""
    import contextlib
    import io
    import json

    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    rng = np.random.default_rng(5)
    images, annotations, detections = [], [], []
    for image_id in range(1, 7):
        images.append({"id": image_id, "file_name": f"{image_id}.jpg", "width": 640, "height": 480})
        for _p in range(int(rng.integers(1, 4))):
            kp = np.zeros((17, 3))
            kp[:, :2] = rng.uniform(50, 400, size=2) + rng.normal(scale=40, size=(17, 2))
            kp[:, 2] = np.where(rng.uniform(size=17) < 0.8, 2, 0)
            kp[kp[:, 2] == 0, :2] = 0
            vis = kp[:, 2] > 0
            x0, y0 = kp[vis, :2].min(0)
            x1, y1 = kp[vis, :2].max(0)
            annotations.append({"id": len(annotations) + 1, "image_id": image_id, "category_id": 1, "iscrowd": 0,
                                "keypoints": kp.reshape(-1).tolist(), "num_keypoints": int(vis.sum()),
                                "bbox": [x0, y0, x1 - x0, y1 - y0], "area": float((x1 - x0) * (y1 - y0))})
            for noise in (3.0, 15.0):                                 # a good and a poor detection
                det = kp.copy()
                det[:, :2] += rng.normal(scale=noise, size=(17, 2))
                det[:, 2] = rng.uniform(0.2, 1.0, 17)
                detections.append({"image_id": image_id, "category_id": 1, "keypoints": det.reshape(-1).tolist(),
                                   "score": float(rng.uniform())})
    gt = {"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "person"}]}
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    (tmp_path / "dt.json").write_text(json.dumps(detections))
    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO(str(tmp_path / "gt.json"))
        ev = COCOeval(coco, coco.loadRes(str(tmp_path / "dt.json")), iouType="keypoints")
        ev.evaluate()
        ev.accumulate()
        ev.summarize()
    ours = metrics.oks_ap(gt, detections)
    assert 0.05 < ev.stats[0] < 0.95                                   # neither trivial nor perfect
    assert ours["AP"] == pytest.approx(ev.stats[0], abs=1e-12) and ours["AP50"] == pytest.approx(ev.stats[1], abs=1e-12)


def test_match_poses_2d_is_one_to_one_and_rejects_far_detections():
    rng = np.random.default_rng(6)
    gt = np.concatenate([rng.uniform(0, 100, (3, 14, 2)) + np.arange(3)[:, None, None] * 300, np.ones((3, 14, 1))], -1)
    pred = gt[[2, 0]].copy()
    pred[:, :, :2] += 2.0
    far = gt[1:2].copy()
    far[:, :, :2] += 1000
    match = metrics.match_poses_2d(np.concatenate([pred, far]), gt)
    assert list(match) == [1, -1, 0]
    assert list(metrics.match_poses_2d(np.zeros((0, 14, 3)), gt)) == [-1, -1, -1]
