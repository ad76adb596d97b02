"""The recap of a rig reconstruction: reprojection error per keypoint, and how often each camera
was excluded (its keypoint rejected by RANSAC) per keypoint. Pure numpy, no I/O."""
from __future__ import annotations

import numpy as np

from mvm.core.keypoints import COCO_KEYPOINTS
from mvm.rig.instants import InstantPersons


def recap(persons: InstantPersons, camera_names, n_instants: int, n_detections: int) -> dict:
    """Summary of ``persons`` over ``n_instants``.

    Returns a JSON-ready dict: ``error_per_keypoint_px`` (mean reprojection error of the inlier
    keypoints, per COCO keypoint), ``excluded_per_camera`` (per camera, per keypoint: the fraction
    of its available keypoints that triangulation rejected), ``views_per_keypoint`` (mean inliers
    per reconstructed joint), and counts.
    """
    inl, valid, err = persons.inliers, persons.valid, persons.errors
    reconstructed = np.isfinite(persons.X).all(-1)                                 # (Q, J)
    used = inl & reconstructed[:, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        err_kp = np.where(used, err, 0).sum((0, 1)) / used.sum((0, 1))             # (J,)
        excluded = (valid & ~inl).sum(0) / valid.sum(0)                            # (V, J)
        views = used.sum((0, 1)) / reconstructed.sum(0)

    def clean(values):
        return [None if not np.isfinite(v) else round(float(v), 4) for v in values]

    names = list(camera_names)
    per_instant = np.bincount(persons.instant, minlength=n_instants) if len(persons) else np.zeros(n_instants)
    all_err = err[used]
    return {
        "instants": int(n_instants),
        "detections": int(n_detections),
        "persons": int(len(persons)),
        "persons_per_instant": round(float(per_instant.mean()), 4) if n_instants else None,
        "reprojection_error_px": round(float(all_err.mean()), 4) if all_err.size else None,
        "keypoints": list(COCO_KEYPOINTS),
        "error_per_keypoint_px": clean(err_kp),
        "views_per_keypoint": clean(views),
        "excluded_per_camera": {names[v]: clean(excluded[v]) for v in range(len(names))},
        "excluded_overall_per_camera": {
            names[v]: (None if valid[:, v].sum() == 0 else round(float((valid[:, v] & ~inl[:, v]).sum()
                                                                      / valid[:, v].sum()), 4))
            for v in range(len(names))},
    }
