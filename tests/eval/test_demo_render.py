"""``mvm demo --render``: the demo's scene with its frames, so report, overlay and export can use them."""
from __future__ import annotations

import cv2
from click.testing import CliRunner

from mvm.cli import main
from mvm.io.scene_dir import read_scene


def test_demo_renders_one_frame_per_camera_of_the_scene(tmp_path):
    result = CliRunner().invoke(main, ["demo", "--people", "2", "--frames", "20", "--render", "-o", str(tmp_path)])
    assert result.exit_code == 0, result.output
    scene = read_scene(tmp_path / "scene")
    frames = sorted(p.name for p in (tmp_path / "scene" / "frames").iterdir())
    assert frames == sorted(scene.cameras.names)
    image = cv2.imread(str(tmp_path / "scene" / "frames" / frames[0]))
    assert (image.shape[1], image.shape[0]) == tuple(int(v) for v in scene.cameras.size[0])
    assert image.std() > 5                                                  # a rendered room, not a blank
