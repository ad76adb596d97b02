"""A clip whose files are corrupt beside a finished result is that clip's failure, recorded in
one line; the driver never crashes on it and the good clips finish; a clip's unusable
supervision is left out of the merged training set."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from test_batch import states, truth_error_mm

from mvm.batch import run_batch
from mvm.errors import InputError
from mvm.io.ground_truth import write_simulation
from mvm.net.supervision import merge_datasets
from mvm.sim.simulate import SimConfig, simulate

#: clip -> (file broken after its reconstruction, new content, text its recorded error holds)
CORRUPT = {
    "x": ("mvm/poses3d.json", "x", "x/mvm/poses3d.json: not valid JSON"),
    "list": ("mvm/poses3d.json", "[]", "list/mvm/poses3d.json: format: expected 'mvm.poses3d/1'"),
    "nan": ("mvm/poses3d.json", None, "metrics.E_R_px: not a finite number (nan)"),
    "poses2d": ("poses2d.json", '{"images": [', "poses2d/poses2d.json: not valid JSON"),
}


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory) -> Path:
    """Five simulated clips, each reconstructed once by a batch run."""
    root = tmp_path_factory.mktemp("bad_clips")
    for i, cid in enumerate([*CORRUPT, "good"]):
        sim = SimConfig(people=2, frames=8, seed=40 + i)
        scene, truth = simulate(sim)
        write_simulation(root / cid, scene, truth, sim)
    summary = run_batch(root, stages=("reconstruct",), workers=1)
    assert not summary.failed and summary.done == 5
    return root


def test_corrupt_files_beside_a_result_fail_only_their_clip(reconstructed, tmp_path):
    root = tmp_path / "root"
    shutil.copytree(reconstructed, root, ignore=shutil.ignore_patterns(".mvm"))   # a fresh manifest
    for cid, (name, content, _) in CORRUPT.items():
        path = root / cid / name
        if content is None:                               # a NaN literal among the metrics
            document = json.loads(path.read_text())
            document["metrics"]["E_R_px"] = float("nan")
            content = json.dumps(document)
        path.write_text(content)
    (root / "fresh").mkdir()                              # a clip not yet reconstructed
    sim = SimConfig(people=2, frames=8, seed=99)
    write_simulation(root / "fresh", *simulate(sim), sim)

    for attempt in range(2):                              # a rerun records the same, never crashes
        summary = run_batch(root, stages=("reconstruct", "export"), workers=1)
        failed = {clip: (stage, error) for clip, stage, error in summary.failed}
        assert set(failed) == set(CORRUPT), attempt
        for cid, (_, _, text) in CORRUPT.items():
            stage, error = failed[cid]
            assert stage == "reconstruct" and text in error and "\n" not in error, (cid, error)
        assert summary.done == 2
    rows = states(root)
    assert rows["x", "reconstruct"]["state"] == "failed"
    assert "not valid JSON" in rows["x", "reconstruct"]["error"]
    for cid in ("good", "fresh"):
        assert rows[cid, "export"]["state"] == "done"
        found, total, mpjpe = truth_error_mm(root, cid)
        assert found == total == 2 and mpjpe < 60
    assert json.loads(summary.training_set.read_text())["images"]


def _dataset(folder: Path, with_ids: bool) -> Path:
    images = [{"file_name": f"f{i}.jpg", "width": 64, "height": 48} | ({"id": i + 1} if with_ids else {})
              for i in range(2)]
    annotations = [{"id": i + 1, "image_id": i + 1, "category_id": 1, "keypoints": [0] * 51} for i in range(2)]
    folder.mkdir()
    path = folder / "annotations.json"
    path.write_text(json.dumps({"images": images, "annotations": annotations, "categories": []}))
    return path


def test_supervision_without_image_ids_is_left_out_of_the_merge(tmp_path):
    good, bad = _dataset(tmp_path / "a", True), _dataset(tmp_path / "b", False)
    with pytest.raises(InputError, match=r"b/annotations.json: images\[0\].id: expected an integer, got None"):
        merge_datasets([good, bad], tmp_path / "merged.json")
    left_out = []
    out = merge_datasets([good, bad], tmp_path / "merged.json", lambda p, e: left_out.append((p, str(e))))
    merged = json.loads(out.read_text())
    assert [im["file_name"] for im in merged["images"]] == ["a/f0.jpg", "a/f1.jpg"]
    assert [a["image_id"] for a in merged["annotations"]] == [1, 2]
    assert left_out == [(bad, f"{bad}: images[0].id: expected an integer, got None")]


def test_a_users_folder_where_a_clip_exports_fails_that_clip_and_stays(reconstructed, tmp_path):
    root = tmp_path / "root"
    shutil.copytree(reconstructed, root, ignore=shutil.ignore_patterns(".mvm"))
    mine = root / "good" / "mvm" / "supervision"
    mine.mkdir()
    (mine / "labels.csv").write_text("my own labels")
    (root / "x" / "mvm" / ".supervision.backup").mkdir()              # a user's folder named like a leftover
    (root / "x" / "mvm" / ".supervision.backup" / "a.json").write_text("{}")
    (root / "x" / "mvm" / "poses3d.json").unlink()                     # x reconstructs again, then exports
    summary = run_batch(root, stages=("reconstruct", "export"), workers=1)
    failed = {clip: (stage, error) for clip, stage, error in summary.failed}
    assert set(failed) >= {"good"} and failed["good"][0] == "export"
    assert "mvm did not make" in failed["good"][1] and "\n" not in failed["good"][1]
    assert [p.name for p in mine.iterdir()] == ["labels.csv"] and (mine / "labels.csv").read_text() == "my own labels"
    assert "x" not in failed and (root / "x" / "mvm" / "supervision" / "annotations.json").is_file()
    assert (root / "x" / "mvm" / ".supervision.backup" / "a.json").read_text() == "{}"
