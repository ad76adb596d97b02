"""From a raw video to a scene directory: frames, SfM cameras, 2D poses and appearance.

Stages (each resumable): :func:`frames.extract_frames`, :func:`sfm.run_sfm` (or
:func:`sfm.import_colmap` / :func:`sfm.import_trajectory`), :func:`detect.detect_scene`,
the metric scale of a reconstruction (:mod:`metric_scale`); :mod:`mvm.stages` runs them. The RTMO /
RTMPose detectors are in :mod:`rtm`, their published models and cache in :mod:`models`.
"""
