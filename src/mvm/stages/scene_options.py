"""The settings of a clip's scene stages: each stage's own settings (the tables ``[reconstruct]``,
``[frames]``, ``[sfm]`` and ``[detect]`` of a settings file, as the single commands read them)
and those of the stages without a table of their own (the ``[batch]`` table)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from mvm.core.config import Config, check_settings, setting
from mvm.io.layout import DEFAULT_OUTPUT

if TYPE_CHECKING:
    from mvm.video.detect import DetectOptions
    from mvm.video.frames import FrameOptions
    from mvm.video.sfm import SfmOptions


def _default(path: str):
    """A factory of the default of the settings dataclass ``module:class``, imported when
    called (the video stages' modules import OpenCV)."""
    def make():
        import importlib

        module, name = path.split(":")
        return getattr(importlib.import_module(module), name)()
    return make


@dataclass(frozen=True)
class SceneOptions:
    """Settings of every stage of a clip (:data:`mvm.stages.SCENE_STAGES`): ``mvm run`` on one
    clip and ``mvm batch`` on many read the same ones and make the same outputs."""

    #: The reconstruction's settings (the ``[reconstruct]`` table). [-]
    config: Config = field(default_factory=Config)
    #: The frame sampling of ``frames`` (the ``[frames]`` table). [-]
    frames: FrameOptions = field(default_factory=_default("mvm.video.frames:FrameOptions"))
    #: The structure from motion of ``sfm`` (the ``[sfm]`` table); in ``mvm batch`` each clip's
    #: SfM runs on one thread, as the clips run in parallel. [-]
    sfm: SfmOptions = field(default_factory=_default("mvm.video.sfm:SfmOptions"))
    #: The 2D detection of ``detect`` (the ``[detect]`` table): ``detector`` "rtmo" or "rtmpose"
    #: detects every clip's frames; None: ``checkpoint``, else each clip's imported detections. [-]
    detect: DetectOptions = field(default_factory=_default("mvm.video.detect:DetectOptions"))
    #: Folder of each scene directory receiving ``poses3d.json`` and the supervision. [name]
    output: str = DEFAULT_OUTPUT
    #: The pose network's checkpoint for ``detect``; None: a detector, or imported detections. [path]
    checkpoint: str | None = None
    #: ``reconstruct``: scale the world (``sparse/`` and the 3D poses) to metres from the
    #: people's bone lengths; false: the scale is only recorded in ``poses3d.json``. A clip
    #: without a video is a scene directory whose cameras are its owner's: they are never
    #: rewritten, its scale only recorded. [-]
    metric_scale: bool = True
    #: ``export``: persons with fewer labelled joints in a frame get no annotation. [joints]
    min_keypoints: int = setting(3, ge=1, le=17)

    def __post_init__(self):
        check_settings(self)

    def replace(self, **changes) -> SceneOptions:
        return dataclasses.replace(self, **changes)
