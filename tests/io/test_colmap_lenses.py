"""COLMAP's camera models read as OpenCV's lenses: the lens read distorts as COLMAP itself does
(pycolmap's ``img_from_cam``), and a model OpenCV cannot express is refused with one line."""
import numpy as np
import pytest

from mvm.core.camera import distort, undistort
from mvm.errors import InputError
from mvm.io.colmap import OPENCV_LENSES, read_colmap

#: Each convertible model's parameters (focal lengths, principal point, then its lens).
PARAMS = {
    "SIMPLE_RADIAL": [600, 320, 240, -0.08], "RADIAL": [600, 320, 240, -0.08, 0.02],
    "OPENCV": [600, 610, 320, 240, -0.08, 0.02, 0.001, -0.002],
    "FULL_OPENCV": [600, 610, 320, 240, -0.08, 0.02, 0.001, -0.002, 0.003, 0.01, -0.004, 0.002],
    "OPENCV_FISHEYE": [400, 405, 320, 240, 0.05, -0.01, 0.002, -0.001],
    "SIMPLE_RADIAL_FISHEYE": [400, 320, 240, 0.05], "RADIAL_FISHEYE": [400, 320, 240, 0.05, -0.01],
    "SIMPLE_FISHEYE": [400, 320, 240], "FISHEYE": [400, 405, 320, 240],
}


def _model(folder, model: str, params) -> None:
    folder.mkdir()
    (folder / "cameras.txt").write_text(f"1 {model} 640 480 {' '.join(map(str, params))}\n")
    (folder / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.jpg\n\n")
    (folder / "points3D.txt").write_text("")


@pytest.mark.parametrize("model", sorted(OPENCV_LENSES))
def test_a_colmap_lens_read_distorts_as_colmap(tmp_path, model):
    import pycolmap

    assert set(PARAMS) == set(OPENCV_LENSES)
    _model(tmp_path / "m", model, PARAMS[model])
    cams = read_colmap(tmp_path / "m").cameras
    K, lens, fisheye = cams.K[0], cams.distortion[0], bool(cams.fisheye[0])
    assert fisheye == ("FISHEYE" in model)
    colmap = pycolmap.Camera(model=model, width=640, height=480, params=PARAMS[model])
    rays = np.random.default_rng(1).uniform([-0.5, -0.4], [0.5, 0.4], (40, 2))       # up to 33° off the axis
    expected = np.asarray(colmap.img_from_cam(np.column_stack([rays, np.ones(40)])), dtype=float)
    pinhole = rays * [K[0, 0], K[1, 1]] + K[:2, 2]
    np.testing.assert_allclose(distort(pinhole, K, lens, fisheye), expected, atol=1e-6)
    np.testing.assert_allclose(undistort(expected, K, lens, fisheye), pinhole, atol=1e-3)
    assert np.abs(expected - pinhole).max() > 1.0                                  # the lens matters


def test_a_model_opencv_cannot_express_is_refused(tmp_path):
    _model(tmp_path / "m", "FOV", [600, 600, 320, 240, 0.9])
    with pytest.raises(InputError, match="camera 1: camera model FOV has no OpenCV equivalent"):
        read_colmap(tmp_path / "m")
