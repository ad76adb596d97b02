"""The report's computations, page and summary, on scenes the tests simulate."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.core.config import Config
from mvm.core.geometry import project
from mvm.errors import InputError
from mvm.io.ground_truth import write_simulation
from mvm.io.scene_dir import read_poses3d, write_scene
from mvm.report import analysis, write_report, write_summary
from mvm.report.plots import bar_chart
from mvm.scenes import reconstruct_dir
from mvm.sim.simulate import SimConfig, simulate

from helpers import standing_poses


def bank() -> np.ndarray:
    """The shipped pose bank, or hand-made standing poses while it is not built."""
    try:
        from mvm.core.posebank import load_pose_bank

        poses = load_pose_bank().poses
    except Exception:  # noqa: BLE001 - the bank's data file may not exist yet
        return standing_poses()
    return poses[np.isfinite(poses).all(axis=(1, 2))]      # complete poses: the truth is written as JSON


def make_scene(path: Path, people: int = 4, frames: int = 24, seed: int = 3, points: int = 0):
    """Simulate, write and reconstruct a scene at ``path``: ``(scene, truth)``."""
    sim = SimConfig(people=people, frames=frames, seed=seed)
    scene, truth = simulate(sim, bank_poses=bank())
    write_simulation(path, scene, truth, sim)
    if points:
        rng = np.random.default_rng(seed)
        cloud = np.concatenate([rng.uniform([-4, -4, 0], [4, 4, 0.01], (points // 2, 3)),
                                rng.uniform([-3, -3, 0], [3, 3, 2.5], (points - points // 2, 3))])
        write_scene(path, scene.cameras, scene.poses, points3d=cloud)
    reconstruct_dir(path, Config(refine=False))
    return scene, truth


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    path = tmp_path_factory.mktemp("report") / "scene"
    make_scene(path, points=300)
    return path


# --- analysis ------------------------------------------------------------------------------

def test_pose_labels_from_members():
    labels = analysis.pose_labels(6, [np.array([0, 3]), np.array([1, 5])])
    assert labels.tolist() == [0, 1, -1, 0, -1, 1]
    with pytest.raises(ValueError, match="out of range"):
        analysis.pose_labels(3, [np.array([3])])


def test_member_errors_measure_the_pixel_offset():
    rng = np.random.default_rng(0)
    from helpers import random_cameras

    cams = random_cameras(rng, 5)
    X = standing_poses(2)                                           # (2, 17, 3)
    X[1, :, 0] += 1.0
    view = np.array([0, 1, 2, 3])
    labels = np.array([0, 1, -1, 1])
    uv, _ = project(X[np.maximum(labels, 0)], cams.P[view])
    keypoints = np.concatenate([uv, np.ones((4, 17, 1))], axis=2)
    keypoints[3, 7, :2] += [3.0, 4.0]                               # 5 px off
    keypoints[1, 2, 2] = 0                                          # missing
    X_missing = X.copy()
    X_missing[0, 16] = np.nan
    errors = analysis.member_errors(X_missing, labels, keypoints, view, cams.P)
    assert errors.shape == (4, 17)
    assert np.isnan(errors[2]).all() and np.isnan(errors[1, 2]) and np.isnan(errors[0, 16])
    assert errors[3, 7] == pytest.approx(5.0, abs=1e-6)
    others = np.delete(errors[[0, 1, 3]].reshape(-1), [16, 17 + 2, 34 + 7])
    assert np.nanmax(others) < 1e-6
    summary = analysis.joint_error_summary(errors)
    assert summary["count"][7] == 3 and summary["count"][16] == 2


def test_frustum_corners_project_to_image_corners():
    from helpers import random_cameras

    cams = random_cameras(np.random.default_rng(1), 3, width=640, height=480)
    fr = analysis.frustums(cams.K, cams.R, cams.t, cams.size, depth=0.5)
    assert fr.shape == (3, 5, 3)
    np.testing.assert_allclose(fr[:, 0], cams.centers, atol=1e-9)
    uv, depth = project(fr[:, 1:], cams.P)
    np.testing.assert_allclose(uv, np.broadcast_to([[0, 0], [640, 0], [640, 480], [0, 480]], (3, 4, 2)), atol=1e-6)
    np.testing.assert_allclose(depth, 0.5, atol=1e-9)


def test_display_frame_puts_up_on_z():
    from helpers import random_cameras

    cams = random_cameras(np.random.default_rng(2), 8)
    up = analysis.up_direction(cams.R)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)           # no roll: rows are horizontal
    same = np.repeat(cams.R[:1], 4, axis=0)                          # one direction: mean -y axis
    np.testing.assert_allclose(analysis.up_direction(same), -cams.R[0, 1], atol=1e-12)
    tilted = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    M, origin = analysis.display_frame(tilted, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(M @ tilted, [0, 0, 1], atol=1e-12)
    assert np.linalg.det(M) == pytest.approx(1.0)


def test_compare_with_truth_finds_shifted_persons():
    truth = standing_poses(3) + np.array([[[0, 0, 0]], [[2, 0, 0]], [[0, 2, 0]]])
    estimate = truth[[2, 0]] + np.array([0.01, 0.0, 0.0])           # 10 mm off, two of three found
    true_person = np.array([0, 0, 1, 2, 2, -1])
    members = [np.array([3, 4]), np.array([0, 1, 5])]               # one false pose grouped
    c = analysis.compare_with_truth(estimate, members, truth, true_person, 0.5)
    assert c["found"] == 2 and c["true"] == 3
    assert c["truth_of"].tolist() == [2, 0]
    assert c["mpjpe"] == pytest.approx(0.01) and c["pa_mpjpe"] < 1e-6
    np.testing.assert_allclose(c["joint_error"], 0.01)
    assert c["precision"] == pytest.approx(2 / 4) and c["recall"] == pytest.approx(2 / 2)


def test_person_colors_are_distinct():
    colors = analysis.person_colors(12).astype(int)
    d = np.abs(colors[:, None] - colors[None]).sum(-1)
    assert d[~np.eye(12, dtype=bool)].min() > 30
    assert analysis.hex_color(colors[0]).startswith("#") and len(analysis.hex_color(colors[0])) == 7


def test_bar_chart_scales_bars_and_skips_nan():
    svg = bar_chart(["a", "b", "c"], [1.0, np.nan, 2.0], "T", "px", whiskers=[1.5, np.nan, 3.0])
    heights = [float(h) for h in re.findall(r'<rect [^>]*height="([0-9.]+)"', svg)]
    assert len(heights) == 2 and heights[1] == pytest.approx(2 * heights[0], rel=1e-3)
    assert svg.count('class="whisker"') == 2 and "b: – px" in svg
    with pytest.raises(ValueError, match="labels"):
        bar_chart(["a"], [1.0, 2.0], "T", "px")


# --- the page ------------------------------------------------------------------------------

def _payload(html: str) -> dict:
    match = re.search(r'<script type="application/json" id="mvm-data">(.*?)</script>', html, re.S)
    assert match, "no data block"
    return json.loads(match.group(1))


def test_report_page_is_self_contained_and_complete(scene_dir):
    path = write_report(scene_dir)
    assert path == scene_dir / "mvm" / "report.html"
    html = path.read_text()
    document = json.loads((scene_dir / "mvm" / "poses3d.json").read_text())
    m = document["metrics"]
    # no resource from the network: no external scripts, styles, images or fonts
    assert not re.search(r'(src|href)="(https?:)?//', html)
    assert "<link" not in html and "@import" not in html
    assert "function basis()" in html                                 # the viewer is inlined
    for section in ("metrics", "view3d", "frames", "plots", "truth", "persons"):
        assert f'id="{section}"' in html
    cards = dict((n, v) for v, n in re.findall(r'<div class="value">([^<]*)</div><div class="name">([^<]*)', html))
    assert cards["persons"] == str(m["persons"])
    assert cards["matched 2D poses"] == str(m["matched_poses"])
    assert cards["unmatched 2D poses"] == str(m["unmatched_poses"])
    assert cards["outliers per 3D pose"] == f"{m['outliers']:.1f}"
    timings = json.loads((scene_dir / "mvm" / "timings.json").read_text())
    for stage in ("matching", "triangulation", "refinement"):
        assert f"<td>{stage}</td><td>{timings[stage + '_s']:.3f}</td>" in html
    assert html.count("data:image/jpeg;base64,") == 8
    assert "no <code>frames/</code> folder" in html
    view = _payload(html)["view"]
    assert len(view["persons"]) == m["persons"]
    assert len(view["truth"]) == 4 and len(view["path"]) == 24
    assert len(view["points"]) // 3 > 200
    assert "Reprojection error per joint" in html and "Views per joint" in html
    assert "3D error per joint against ground truth" in html


def test_report_view_keeps_geometry(scene_dir):
    """The display frame is a rigid motion: distances between persons' joints survive."""
    from mvm.io.scene_dir import read_scene

    html = write_report(scene_dir, frames=0).read_text()
    assert "data:image/jpeg" not in html
    view = _payload(html)["view"]
    persons = read_poses3d(scene_dir / "mvm" / "poses3d.json", read_scene(scene_dir).poses)
    X = persons.keypoints3d
    shown = np.array([[j if j is not None else [np.nan] * 3 for j in p["joints"]] for p in view["persons"]])
    pairs = np.isfinite(X[:, 0]).all(-1)
    a, b = X[pairs][:, 0], X[0, 5]
    sa, sb = shown[pairs][:, 0], shown[0, 5]
    np.testing.assert_allclose(np.linalg.norm(a - b, axis=-1), np.linalg.norm(sa - sb, axis=-1), atol=1e-3)
    # up is up: the view's heights follow the simulated world's z (metres, z up)
    ok = np.isfinite(X).all(-1) & np.isfinite(shown).all(-1)
    assert np.corrcoef(X[ok][:, 2], shown[ok][:, 2])[0, 1] > 0.99
    assert view["grid"]["z"] <= np.nanmin(shown[..., 2]) + 1e-6


def test_report_needs_a_reconstruction(tmp_path):
    scene, truth = simulate(SimConfig(people=2, frames=8, seed=1), bank_poses=bank())
    write_simulation(tmp_path / "raw", scene, truth)
    with pytest.raises(InputError, match="poses3d.json"):
        write_report(tmp_path / "raw")


def test_summary_links_every_existing_report(tmp_path, scene_dir):
    other = tmp_path / "data" / "b scene"
    make_scene(other, people=3, frames=12, seed=5)
    write_report(other, frames=2)
    first = write_report(scene_dir, frames=2)
    missing = tmp_path / "data" / "c"
    missing.mkdir()
    path = write_summary(tmp_path / "data", [scene_dir, other, missing])
    html = path.read_text()
    hrefs = re.findall(r'href="([^"]+)"', html)
    assert len(hrefs) == 2
    from urllib.parse import unquote

    targets = {(path.parent / unquote(h)).resolve() for h in hrefs}
    assert targets == {first.resolve(), (other / "mvm" / "report.html").resolve()}
    assert "c <span class=\"note\">(no report)</span>" in html and "not reconstructed" in html
    metrics = json.loads((other / "mvm" / "poses3d.json").read_text())["metrics"]
    assert f"<td>{metrics['matched_poses']}</td>" in html


def test_report_command(scene_dir, tmp_path):
    from mvm.cli.report import report_cmd

    result = CliRunner().invoke(report_cmd, [str(scene_dir), "--frames", "1"])
    assert result.exit_code == 0, result.output
    assert "report.html" in result.output
    bad = CliRunner().invoke(report_cmd, [str(tmp_path / "nowhere")])
    assert bad.exit_code == 2 and "mvm: error:" in bad.output


@pytest.mark.parametrize("key, value", [("timings_s", "fast"), ("timings_s", [1, 2]), ("metrics", "good")])
def test_a_metrics_or_timings_field_of_the_wrong_type_is_one_line(scene_dir, tmp_path, key, value):
    """(``timings_s``: where a ``poses3d.json`` of an earlier version kept the seconds.)"""
    import shutil

    copy = tmp_path / "scene"
    shutil.copytree(scene_dir, copy)
    (copy / "mvm" / "timings.json").unlink()
    path = copy / "mvm" / "poses3d.json"
    document = json.loads(path.read_text())
    document[key] = value
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match=rf"poses3d\.json: {key}: expected an object") as e:
        write_report(copy, frames=1)
    assert "\n" not in str(e.value)


def test_timings_that_are_not_finite_numbers_are_left_out(scene_dir, tmp_path):
    import shutil

    from mvm.report.load import load_result

    copy = tmp_path / "scene"
    shutil.copytree(scene_dir, copy)
    path = copy / "mvm" / "timings.json"
    path.write_text(json.dumps({"a_s": 1.5, "b_s": "x", "c_s": 10 ** 400, "d_s": True, "e_s": None}))
    assert load_result(copy).timings == {"a_s": 1.5}
    write_report(copy, frames=1)


def test_report_is_never_written_over_or_among_the_scenes_inputs(scene_dir, tmp_path):
    from mvm.io.files import OutputError

    for path, problem in ((scene_dir / "poses2d.json", "is an input of this run"),
                          (scene_dir / "sparse" / "report.html", "lies inside the input folder"),
                          (scene_dir / "mvm" / "poses3d.json", "is an input of this run"),
                          (scene_dir / "mvm" / "timings.json", "is an input of this run")):
        before = path.read_bytes() if path.is_file() else None
        with pytest.raises(OutputError, match=problem):
            write_report(scene_dir, path=path)
        assert (path.read_bytes() if path.is_file() else None) == before
    assert write_report(scene_dir, path=tmp_path / "r.html").is_file()


def test_summary_never_replaces_what_mvm_did_not_write(tmp_path, scene_dir):
    """A user's own summary.html, a folder or a link of that name stays as it is, refused in one
    line; mvm's own page is rewritten."""
    from mvm.io.files import OutputError

    root = tmp_path / "data"
    root.mkdir(exist_ok=True)
    page = root / "summary.html"
    page.write_text("<html>my notes</html>")
    with pytest.raises(OutputError, match="not a summary page mvm wrote"):
        write_summary(root, [scene_dir])
    assert page.read_text() == "<html>my notes</html>"
    page.unlink()
    page.mkdir()
    with pytest.raises(OutputError, match="not a file"):
        write_summary(root, [scene_dir])
    page.rmdir()
    page.symlink_to(tmp_path / "elsewhere.html")
    with pytest.raises(OutputError, match="not a file"):
        write_summary(root, [scene_dir])
    assert not (tmp_path / "elsewhere.html").exists()
    page.unlink()
    first = write_summary(root, [scene_dir]).read_text()
    assert write_summary(root, [scene_dir]).read_text() == first


@pytest.mark.parametrize("kind", ["not json", "a list", "a link out of the scene", "a fifo"])
def test_a_hostile_timings_file_is_one_line_or_passed_over(scene_dir, tmp_path, kind):
    """``mvm/timings.json`` is read as any input: text that is no JSON object, a link leading out
    of the scene is one line naming it; a FIFO is not waited on (no seconds shown)."""
    import os
    import shutil

    from mvm.report.load import load_result

    copy = tmp_path / "scene"
    shutil.copytree(scene_dir, copy)
    path = copy / "mvm" / "timings.json"
    path.unlink()
    if kind == "not json":
        path.write_text("{seconds")
    elif kind == "a list":
        path.write_text("[1, 2]")
    elif kind == "a link out of the scene":
        (tmp_path / "elsewhere.json").write_text('{"a_s": 1}')
        path.symlink_to(tmp_path / "elsewhere.json")
    else:
        os.mkfifo(path)
        assert load_result(copy).timings == {}
        return
    with pytest.raises(InputError, match="timings.json") as e:
        load_result(copy)
    assert "\n" not in str(e.value)
