"""Every settings dataclass checks its fields when built (check_settings in __post_init__): a
value of the wrong type and a value out of range are refused, naming the setting."""
from __future__ import annotations

import dataclasses
import importlib

import pytest

from mvm.core.config import Bounds, check_settings, setting_kind
from mvm.errors import InputError

CLASSES = ["mvm.core.config:Config", "mvm.rig.options:RigOptions", "mvm.sim.simulate:SimConfig",
           "mvm.sim.mannequin_video:RenderConfig", "mvm.sim.detector:DetectorErrors", "mvm.video.frames:FrameOptions",
           "mvm.video.sfm:SfmOptions", "mvm.stages.scene_options:SceneOptions", "mvm.video.detect:DetectOptions",
           "mvm.video.rtm:RtmOptions", "mvm.core.matching.baselines:BaselineConfig", "mvm.net.decoder:DecoderConfig",
           "mvm.net.encoder:EncoderConfig", "mvm.net.data:AugmentConfig", "mvm.net.losses:LossWeights"]


def _class(path: str):
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


def _out_of_range(bounds: Bounds, kind: str):
    """A value of ``kind`` that ``bounds`` refuse."""
    if bounds.ge is not None:
        value = bounds.ge - 1
    elif bounds.gt is not None:
        value = bounds.gt
    elif bounds.le is not None:
        value = bounds.le + 1
    else:
        value = bounds.lt
    return int(value) - (kind == "int" and value != int(value)) if kind == "int" else float(value)


@pytest.mark.parametrize("path", CLASSES)
def test_wrong_type_and_out_of_range_are_refused(path):
    cls = _class(path)
    check_settings(cls())
    numbers = [f for f in dataclasses.fields(cls) if setting_kind(f)[0] in ("int", "float")]
    assert numbers, f"{cls.__name__} has no number setting"
    for field in numbers:
        kind = setting_kind(field)[0]
        with pytest.raises(InputError, match=f"^{field.name}: expected {kind}, got 'x'$"):
            cls(**{field.name: "x"})
        bounds = field.metadata.get("bounds")
        assert bounds is not None and (bounds.ge is not None or bounds.gt is not None), \
            f"{cls.__name__}.{field.name} has no lower bound"
        with pytest.raises(InputError, match=f"^{field.name}: must be "):
            cls(**{field.name: _out_of_range(bounds, kind)})
    for field in dataclasses.fields(cls):
        choices = field.metadata.get("bounds", Bounds()).choices
        if choices:
            with pytest.raises(InputError, match=f"^{field.name}: expected one of "):
                cls(**{field.name: "no such choice"})


def test_ranges_that_go_together():
    from mvm.net.data import AugmentConfig
    from mvm.sim.simulate import SimConfig

    with pytest.raises(InputError, match="^crop_min: must be <= crop_max"):
        AugmentConfig(crop_min=0.9, crop_max=0.8)
    with pytest.raises(InputError, match="^noise: must be >= 0"):          # the detector's, by its own name
        SimConfig().replace(noise=-0.1)
    with pytest.raises(InputError, match="^people: must be >= 1, got 0$"):
        SimConfig.preset("clean", people=0)
