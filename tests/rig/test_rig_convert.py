"""``mvm rig calibrate RIG_DIR --convert FILE``: the rig's cameras matched by name, a recap,
Calib.toml written; bad input one line, exit 2, nothing written."""
from __future__ import annotations

import pickle

import numpy as np
from click.testing import CliRunner

from calibration_writers import known_cameras, write_easymocap, write_opencap, write_qca, write_xcp
from mvm.cli.rig import rig
from mvm.io.calib_toml import read_calib_toml


def _rig(tmp_path, names):
    root = tmp_path / "rig"
    (root / "videos").mkdir(parents=True)
    for name in names:
        (root / "videos" / f"{name}.mp4").write_bytes(b"")
    return root


def _convert(root, source, out, *args):
    return CliRunner().invoke(rig, ["calibrate", str(root), "--convert", str(source), "-o", str(out), *args])


def _one_line_exit_2(result, out, *words):
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    for word in words:
        assert word in lines[0], lines[0]
    assert not out.exists()


def test_convert_keeps_the_rig_cameras_and_prints_a_recap(tmp_path):
    cams = known_cameras(4)
    source = write_qca(tmp_path / "lab.qca.txt", cams)
    root = _rig(tmp_path, ["cam01", "cam02", "cam04"])
    out = root / "Calib.toml"
    result = _convert(root, source, out)
    assert result.exit_code == 0, result.output
    assert "converted from qualisys" in result.output and f"wrote {out}" in result.output
    assert "left out (not in the rig): cam03" in result.output
    assert f"{cams[0].K[0, 0] * 0.5 + cams[0].K[1, 1] * 0.5:.1f}" in result.output
    written = read_calib_toml(out)
    assert written.cameras.names == ("cam01", "cam02", "cam04")
    np.testing.assert_allclose(written.cameras.centers, [cams[i].center for i in (0, 1, 3)], atol=1e-9)
    assert written.metadata["format"] == "qualisys" and written.metadata["left_out"] == ["cam03"]


def test_convert_a_rig_without_cameras_writes_all(tmp_path):
    cams = known_cameras(2)
    root = tmp_path / "empty"
    root.mkdir()
    out = tmp_path / "c.toml"
    result = _convert(root, write_xcp(tmp_path / "v.xcp", cams), out, "--format", "vicon")
    assert result.exit_code == 0, result.output
    assert "every camera kept" in result.output
    assert read_calib_toml(out).cameras.names == ("cam01", "cam02")


def test_convert_refusals(tmp_path):
    cams = known_cameras(3)
    root = _rig(tmp_path, ["cam01", "cam02", "cam03", "cam04"])
    out = tmp_path / "c.toml"
    qca = write_qca(tmp_path / "lab.qca.txt", cams)
    _one_line_exit_2(_convert(root, qca, out), out, "no camera for cam04")
    xcp = write_xcp(tmp_path / "v.xcp", cams)
    _one_line_exit_2(_convert(root, xcp, out, "--format", "qualisys"), out, "not a Qualisys calibration")
    truncated = tmp_path / "cut.qca.txt"
    truncated.write_text(qca.read_text()[:1000])
    _one_line_exit_2(_convert(root, truncated, out), out, "XML")
    _one_line_exit_2(_convert(root, qca, out, "--charuco"), out, "choose one of", "--convert")
    _one_line_exit_2(_convert(root, qca, out, "--board-size", "7x6"), out, "--board-size", "--convert")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--from-people", "--binning", "2", "-o",
                                              str(out)]), out, "--binning", "--convert only")
    _one_line_exit_2(_convert(root, xcp, out, "--binning", "2"), out, "--binning", "Qualisys")
    text = qca.read_text()
    result = _convert(root, qca, qca)
    assert result.exit_code == 2 and "is an input" in result.output and qca.read_text() == text


def test_convert_never_writes_over_a_file_it_reads(tmp_path):
    """The output named as EasyMocap's other file, or as one of the rig's videos: refused in one
    line before any write, the file untouched (both were overwritten)."""
    cams = known_cameras(3)
    folder = tmp_path / "calib"
    folder.mkdir()
    intri = write_easymocap(folder, cams)
    extri = folder / "extri.yml"
    root = _rig(tmp_path, ["cam01", "cam02", "cam03"])
    video = root / "videos" / "cam02.mp4"
    video.write_bytes(b"frames")
    for out, original in ((extri, extri.read_bytes()), (video, b"frames")):
        result = _convert(root, folder / "intri.yml" if intri.is_dir() else intri, out)
        assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
        assert "is an input" in result.output and out.read_bytes() == original


class _RunsCode:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        import os

        return os.system, (f"touch {self.marker}",)


def test_convert_refuses_a_pickle_that_would_run_code(tmp_path):
    cams = known_cameras(2)
    first = write_opencap(tmp_path / "Videos", cams)
    marker = tmp_path / "ran"
    (first.parent.parent / "Cam1" / first.name).write_bytes(pickle.dumps({"rotation": _RunsCode(marker)}))
    out = tmp_path / "c.toml"
    root = tmp_path / "empty"
    root.mkdir()
    _one_line_exit_2(_convert(root, first, out), out, "refusing to load", "system")
    assert not marker.exists()
