"""mvm: multi-person 3D human poses from many views of a static scene (MVM matching,
triangulation, refinement), and the supervision to train a monocular 3D pose network.

The Python API mirrors the command line::

    import mvm
    result = mvm.reconstruct_dir("scene/")           # mvm reconstruct scene/
    for path, outcome in mvm.reconstruct_dirs(["a/", "b/"]):     # mvm reconstruct a/ b/
        ...                                          # a Result, or the error of that scene
    scene = mvm.read_scene("scene/")
    result = mvm.reconstruct(scene, mvm.Config(tau=0.25))
    results = mvm.reconstruct_many([scene, ...])     # many scenes, one refinement solve

``import mvm`` is cheap: the names below are imported on first use.
"""
from __future__ import annotations

import importlib

__version__ = "0.2.0"

#: Public name -> the module that defines it.
_EXPORTS = {
    "Cameras": "mvm.core.scene",
    "Persons3D": "mvm.core.scene",
    "Poses2D": "mvm.core.scene",
    "Scene": "mvm.core.scene",
    "Config": "mvm.core.config",
    "load_config": "mvm.settings.tables",
    "InputError": "mvm.errors",
    "Result": "mvm.core.reconstruct",
    "reconstruct": "mvm.core.reconstruct",
    "reconstruct_many": "mvm.core.reconstruct",
    "reconstruct_dir": "mvm.scenes",
    "reconstruct_dirs": "mvm.scenes",
    "read_poses3d": "mvm.io.scene_dir",
    "read_scene": "mvm.io.scene_dir",
    "write_scene": "mvm.io.scene_dir",
}

__all__ = ["Cameras", "Config", "InputError", "Persons3D", "Poses2D", "Result", "Scene", "__version__",
           "load_config", "read_poses3d", "read_scene", "reconstruct", "reconstruct_dir", "reconstruct_dirs",
           "reconstruct_many", "write_scene"]


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mvm' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
