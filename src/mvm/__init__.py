"""mvm: multi-person 3D human poses from many views of a static scene (MVM matching,
triangulation, refinement), and the supervision to train a monocular 3D pose network.

The Python API mirrors the command line::

    import mvm
    result = mvm.reconstruct_dir("scene/")           # mvm reconstruct scene/
    scene = mvm.read_scene("scene/")
    result = mvm.core.reconstruct(scene, mvm.Config(tau=0.25))
"""
from mvm.errors import InputError

#: Public names and the modules that define them, imported on first use (``import mvm`` stays
#: light, so that ``mvm --help`` does not load scipy).
_LAZY = {"Config": "mvm.core.config", "load_config": "mvm.core.config", "Result": "mvm.core.reconstruct",
         "reconstruct": "mvm.core.reconstruct", "reconstruct_dir": "mvm.core.reconstruct",
         "Cameras": "mvm.core.scene", "Persons3D": "mvm.core.scene", "Poses2D": "mvm.core.scene",
         "Scene": "mvm.core.scene", "read_poses3d": "mvm.io.scene_dir", "read_scene": "mvm.io.scene_dir",
         "write_scene": "mvm.io.scene_dir"}

__version__ = "0.1.0"

__all__ = ["Cameras", "Config", "InputError", "Persons3D", "Poses2D", "Result", "Scene",
           "load_config", "read_poses3d", "read_scene", "reconstruct", "reconstruct_dir", "write_scene",
           "__version__"]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mvm' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
