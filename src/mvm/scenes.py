"""The scene-directory driver: read ``scene/``, reconstruct it (:func:`mvm.core.reconstruct.reconstruct`),
write ``scene/<output>/poses3d.json`` under a lock (the directory contract: docs/architecture.md)."""
from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

from mvm.core.config import Config
from mvm.core.reconstruct import Result, check_affinity_memory, reconstruct, validate_scene
from mvm.errors import InputError
from mvm.io.files import LockTimeout, exclusive_lock, remove_stale_temporaries
from mvm.io.scene_dir import output_dir, poses3d_document, read_scene, write_poses3d


def reconstruct_dir(path: str | Path, config: Config | None = None, output: str = "mvm",
                    prior=None) -> Result:
    """Read a scene directory, reconstruct it and write ``<path>/<output>/poses3d.json``.

    Bad input raises :class:`~mvm.errors.InputError` naming the file before anything is written.
    """
    config = config or Config()
    path = Path(path)
    t = time.perf_counter()
    scene = read_scene(path)
    out_dir = output_dir(path, output)
    read_s = time.perf_counter() - t
    validate_scene(scene, str(path))
    check_affinity_memory(len(scene.poses), config.use_appearance and scene.poses.appearance is not None,
                          config, str(path / "poses2d.json"))
    result = reconstruct(scene, config, prior)
    result.timings = {"read_s": read_s, **result.timings}
    document = poses3d_document(result.persons, scene.poses, result.metrics,
                                {"warnings": list(result.warnings),
                                 "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
                                 "config": asdict(config)})
    # Runs on the same scene may compute at once; writing is one at a time, and the temporary
    # files of a killed run are removed by the next one.
    try:
        with exclusive_lock(out_dir, config.lock_timeout_s):
            remove_stale_temporaries(out_dir, "poses3d.json")
            write_poses3d(out_dir / "poses3d.json", document)
    except LockTimeout:
        raise InputError(out_dir, None, f"another mvm run has been writing here for more than "
                                        f"{config.lock_timeout_s:g} s (lock_timeout_s)") from None
    return result
