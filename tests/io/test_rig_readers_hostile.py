"""Hostile rig result files — a rig's ``poses3d.jsonl`` and a simulated rig's ground truth —
are one :class:`InputError` naming the file and the field: malformed JSON, a FIFO (no hang), a
folder, wrong shapes, numbers too large for their type; never another exception."""
from __future__ import annotations

import json
import os

import pytest

from mvm.errors import InputError
from mvm.io.rig_poses3d import RIG_POSES3D_FORMAT, read_rig_poses3d
from mvm.io.rig_simulation import TRUTH_FORMAT
from mvm.io.rig_truth import read_rig_truth


def _truth(**change) -> dict:
    doc = {"format": TRUTH_FORMAT, "cameras": ["a", "b"], "extrinsics": {"a": {"center": [0, 0, 0]},
                                                                        "b": {"center": [1, 0, 0]}},
           "offsets": {"a": 0, "b": 2}, "instants": [0, 1], "poses3d": [[[[0.0, 0.0, 1.0]] * 17]] * 2}
    doc.update(change)
    return doc


def test_a_good_truth_reads(tmp_path):
    path = tmp_path / "rig.groundtruth.json"
    path.write_text(json.dumps(_truth()))
    truth = read_rig_truth(path)
    assert truth.poses3d.shape == (2, 1, 17, 3) and truth.offsets == {"a": 0, "b": 2}


@pytest.mark.parametrize("change, field", [
    ({"instants": [2**64, 1]}, "poses3d"), ({"instants": [1e300, 1]}, "poses3d"),
    ({"instants": [float("nan"), 1]}, "poses3d"), ({"instants": "ab"}, "poses3d"),
    ({"poses3d": [[[[0.0, 0.0]] * 17]] * 2}, "poses3d"), ({"poses3d": [[[[1e400, 0, 0]] * 17]] * 2}, "poses3d"),
    ({"poses3d": {"x": 1}}, "poses3d"), ({"extrinsics": {"a": 3, "b": {}}}, "extrinsics.a.center"),
    ({"extrinsics": {"a": {"center": [0, 0]}, "b": {"center": [1, 0, 0]}}}, "extrinsics.a.center"),
    ({"offsets": {"a": 0.5, "b": 2}}, "offsets"), ({"cameras": "ab"}, "cameras"), ({"format": 1}, "format")])
def test_a_bad_truth_is_one_line(tmp_path, change, field):
    path = tmp_path / "rig.groundtruth.json"
    path.write_text(json.dumps(_truth(**change)).replace("1e+400", "1e400"))
    with pytest.raises(InputError) as e:
        read_rig_truth(path)
    assert str(path) in str(e.value) and field in str(e.value) and "\n" not in str(e.value)


def _instant(frame=0, **person) -> str:
    p = {"id": 1, "keypoints3d": [[0.0, 0.0, 1.0, 0.9]] * 17}
    p.update(person)
    return json.dumps({"format": RIG_POSES3D_FORMAT, "frame": frame, "persons": [p]})


@pytest.mark.parametrize("text, field", [
    ("{", "line 1"), (_instant() + "\n" + _instant(), "line 2: frame"), ("[" * 100_000, "line 1"),
    (_instant(id=2**70), None), (_instant(members={"a": 2**70}), None),
    (_instant(views_per_joint=[2**70] * 17), None), (_instant(keypoints3d="x"), "keypoints3d"),
    (_instant(frame=2**70), None), ("", None), ('"' + "x" * 3_000_000 + '"', "line 1"),
    (_instant(keypoints3d=[[10**400, 0, 1, 0.9]] * 17), "keypoints3d"),
    (_instant(reprojection_error_px=10**400), "reprojection_error_px"),
    (_instant(reprojection_error_px=float("nan")), "reprojection_error_px"),
    (_instant(reprojection_error_px="1"), "reprojection_error_px"),
    (_instant(views_per_joint=[-1] * 17), "views_per_joint")])
def test_a_bad_poses3d_is_one_line(tmp_path, text, field):
    path = tmp_path / "poses3d.jsonl"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        read_rig_poses3d(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    assert field is None or field in str(e.value)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_or_folder_is_one_line_not_a_hang(tmp_path):
    for name, read in (("poses3d.jsonl", read_rig_poses3d), ("rig.groundtruth.json", read_rig_truth)):
        os.mkfifo(tmp_path / name)
        with pytest.raises(InputError, match="FIFO"):
            read(tmp_path / name)
        os.unlink(tmp_path / name)
        (tmp_path / name).mkdir()
        with pytest.raises(InputError, match="directory"):
            read(tmp_path / name)
        (tmp_path / name).rmdir()
