"""mvm: multi-person 3D human poses from many views of a static scene (MVM matching,
triangulation, refinement), and the supervision to train a monocular 3D pose network.

The Python API mirrors the command line::

    import mvm
    result = mvm.reconstruct_dir("scene/")           # mvm reconstruct scene/
    scene = mvm.read_scene("scene/")
    result = mvm.core.reconstruct(scene, mvm.Config(tau=0.25))
"""
from mvm.core.config import Config, load_config
from mvm.core.reconstruct import Result, reconstruct, reconstruct_dir
from mvm.core.scene import Cameras, Persons3D, Poses2D, Scene
from mvm.errors import InputError
from mvm.io.scene_dir import read_poses3d, read_scene, write_scene

__version__ = "0.1.0"

__all__ = ["Cameras", "Config", "InputError", "Persons3D", "Poses2D", "Result", "Scene",
           "load_config", "read_poses3d", "read_scene", "reconstruct", "reconstruct_dir", "write_scene",
           "__version__"]
