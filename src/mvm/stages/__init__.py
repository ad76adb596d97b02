"""The stages of the pipeline, one object each (:class:`Stage`), and the runner that takes a
clip through them (:func:`run_stages`).

``mvm run`` runs :data:`SCENE_STAGES` on one clip, ``mvm batch`` maps many clips over the same
list on a process pool or Ray, and ``mvm status`` reads the same declarations to say what is
out of date. A new stage is one module declaring its ``STAGE`` and one line in the list.
"""
from __future__ import annotations

from mvm.stages import (
    rig_calibrate,
    rig_detect,
    rig_reconstruct,
    rig_synchronize,
    scene_detect,
    scene_export,
    scene_frames,
    scene_reconstruct,
    scene_sfm,
    view_overlay,
    view_report,
)
from mvm.stages.scene_options import SceneOptions
from mvm.stages.stage import Done, Job, RigJob, Stage
from mvm.stages.stage_runner import run_stage, run_stages

#: The scene stages in pipeline order: a video's frames, its cameras, its 2D poses, the 3D
#: poses in metres, and the supervision of the network.
SCENE_STAGES: tuple[Stage, ...] = (
    scene_frames.STAGE,
    scene_sfm.STAGE,
    scene_detect.STAGE,
    scene_reconstruct.STAGE,
    scene_export.STAGE,
)
#: The stages ``mvm run`` runs (the export is ``mvm batch``'s, for the merged training set).
RUN_STAGES = SCENE_STAGES[:4]
#: The stages of a rig folder (:class:`RigJob`), in the order of the user's path: its videos' 2D
#: poses (``mvm rig detect``), its cameras' frame offsets (``mvm rig synchronize``), a
#: calibration (``mvm rig calibrate``) and its reconstruction (``mvm rig reconstruct``).
RIG_STAGES: tuple[Stage, ...] = (
    rig_detect.STAGE,
    rig_synchronize.STAGE,
    rig_calibrate.STAGE,
    rig_reconstruct.STAGE,
)

#: The stages that draw a reconstruction, a scene's or a rig's (:class:`~mvm.stages.view.ViewJob`):
#: its HTML page (``mvm report``) and its overlays (``mvm overlay``).
VIEW_STAGES: tuple[Stage, ...] = (
    view_report.STAGE,
    view_overlay.STAGE,
)


def scene_stage(name: str) -> Stage:
    """The scene stage called ``name``."""
    for stage in SCENE_STAGES:
        if stage.name == name:
            return stage
    raise ValueError(f"unknown stage {name!r}: expected one of {', '.join(s.name for s in SCENE_STAGES)}")


__all__ = ["SCENE_STAGES", "RUN_STAGES", "RIG_STAGES", "VIEW_STAGES", "Done", "Job", "RigJob", "SceneOptions", "Stage",
           "run_stage", "run_stages", "scene_stage"]
