"""Metrics against ground truth: arrays in, numbers out, no file I/O, importing only
:mod:`mvm.core` and :mod:`mvm.errors` (numpy and scipy; pycocotools for OKS AP, imported
where used).

- :mod:`mvm.metrics.poses`: matching precision / recall, person matching, MPJPE, PA-MPJPE and
  the similarity (Procrustes) alignment behind it;
- :mod:`mvm.metrics.mocap_scores`: the motion-capture field's PCP (Shelf/Campus) and AP (Panoptic);
- :mod:`mvm.metrics.network`: the monocular network's metrics: PA-MPJPE in the 3DPW protocol,
  2D matching of detections, OKS AP, C_var, relative depth error.

The paper's proxies without ground truth (E_R, outliers, |G_k|) are in :mod:`mvm.core.quality`;
the experiments that compute these metrics (demo, benchmarks, Panoptic, C_var of scenes) are in
:mod:`mvm.eval`.
"""
