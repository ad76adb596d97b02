""".trc: the OpenSim / Pose2Sim layout read, round trip, Y-up conversion."""
import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.trc import read_trc, to_opensim, trc_text, write_trc

# Pose2Sim's header (make_trc) followed by two frames, the second missing its second marker.
PUBLISHED = (
    "PathFileType\t4\t(X/Y/Z)\tdemo.trc\n"
    "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
    "60\t60\t2\t2\tm\t60\t10\t11\n"
    "Frame#\tTime\tHip\t\t\tNeck\t\t\n"
    "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
    "\n"
    "10\t0.000000\t0.1\t0.9\t0.2\t0.1\t1.5\t0.2\n"
    "11\t0.016667\t0.11\t0.91\t0.21\t\t\t\n"
)


def test_read_published_layout(tmp_path):
    path = tmp_path / "demo.trc"
    path.write_text(PUBLISHED)
    trc = read_trc(path)
    assert trc.markers == ("Hip", "Neck")
    assert trc.rate == 60 and trc.units == "m"
    assert trc.frames.tolist() == [10, 11]
    np.testing.assert_allclose(trc.points[0], [[0.1, 0.9, 0.2], [0.1, 1.5, 0.2]])
    assert np.isnan(trc.points[1, 1]).all() and np.isfinite(trc.points[1, 0]).all()


def test_round_trip_and_header(tmp_path):
    rng = np.random.default_rng(0)
    points = rng.normal(size=(5, 3, 3))
    points[2, 1] = np.nan
    write_trc(tmp_path / "p.trc", points, ["a", "b", "c"], 25.0, frames=np.arange(100, 105))
    lines = (tmp_path / "p.trc").read_text().splitlines()
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\tp.trc"
    assert lines[2].split("\t") == ["25", "25", "5", "3", "m", "25", "100", "5"]
    assert lines[4].split("\t")[2:5] == ["X1", "Y1", "Z1"]
    trc = read_trc(tmp_path / "p.trc")
    np.testing.assert_allclose(trc.points, points, atol=1e-6)
    np.testing.assert_allclose(trc.times, np.arange(5) / 25.0)


def test_to_opensim_is_a_rotation_to_y_up():
    z_up = np.array([[0.3, -0.2, 1.7]])
    y_up = to_opensim(z_up, "+z")
    assert y_up[0, 1] == pytest.approx(1.7)                     # height on Y, as Pose2Sim
    np.testing.assert_allclose(to_opensim(np.array([[0, -1.0, 0]]), "-y", 0.01), [[0, 0.01, 0]])
    for up in ("+z", "-z", "-y"):
        from mvm.io.trc import UP_ROTATIONS
        assert np.linalg.det(UP_ROTATIONS[up]) == pytest.approx(1.0)


def test_bad_files(tmp_path):
    with pytest.raises(ValueError, match="expected points"):
        trc_text(np.zeros((2, 3, 3)), ["a", "b"], 30)
    path = tmp_path / "bad.trc"
    path.write_text(PUBLISHED.replace("0.11\t0.91", "x\t0.91"))
    with pytest.raises(InputError, match="line 8"):
        read_trc(path)
