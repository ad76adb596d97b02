"""The report and the overlays of a rig, against the simulator's truth: a rig with frame offsets
(sync.toml) and a fault put into one camera over ten frames, reconstructed, then drawn. The page
holds one instant per reconstructed instant and every track, its joint angles agree with the
true bodies', each camera's reprojection error equals an independent computation and shows the
fault where it was put; the overlays land on the true joints' projections. Bad inputs are one
line, exit 2, nothing written."""
from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

cv2 = pytest.importorskip("cv2")

from mvm.cli.main import main  # noqa: E402
from mvm.core.completion import INFERRED, INTERPOLATED, MISSING, OBSERVED  # noqa: E402
from mvm.core.config import Config  # noqa: E402
from mvm.core.joint_angles import flexion_angles  # noqa: E402
from mvm.io.calib_toml import read_calib_toml  # noqa: E402
from mvm.io.rig_poses3d import read_rig_poses3d  # noqa: E402
from mvm.io.rig_simulation import write_rig_simulation  # noqa: E402
from mvm.io.sync_toml import write_sync_toml  # noqa: E402
from mvm.report import rig_analysis  # noqa: E402
from mvm.rig.options import RigOptions  # noqa: E402
from mvm.rig.reconstruct_rig import reconstruct_rig  # noqa: E402
from mvm.sim.rig_scene import RigSimConfig, simulate_rig  # noqa: E402

OFFSETS = (0, 3, -2, 1)
#: The fault: camera 3's keypoints moved this far right over its frames FAULT (px).
FAULT_PX = 40.0
FAULT = range(20, 30)
#: Test videos are this fraction of the calibration's image size.
VIDEO_SCALE = 0.25
BACKGROUND = 30


def _fault(root: Path, camera: str) -> None:
    path = root / "pose" / f"{camera}.json"
    document = json.loads(path.read_text())
    frame = {im["id"]: int(Path(im["file_name"]).stem) for im in document["images"]}
    for a in document["annotations"]:
        if frame[a["image_id"]] in FAULT:
            kp = np.array(a["keypoints"], dtype=float).reshape(17, 3)
            kp[kp[:, 2] > 0, 0] += FAULT_PX
            a["keypoints"] = kp.ravel().tolist()
    path.write_text(json.dumps(document))


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A reconstructed rig (4 cameras, 3 people, 50 frames, offsets, the fault in cam_03) and its truth."""
    root = tmp_path_factory.mktemp("rigreport") / "rig1"
    sim = simulate_rig(RigSimConfig(cameras=4, people=3, frames=50, offsets=OFFSETS, seed=4))
    write_rig_simulation(root, sim)
    names = list(sim.calibration.cameras.names)
    write_sync_toml(root / "sync.toml", dict(zip(names, sim.sync_offsets.tolist())))
    _fault(root, names[2])
    reconstruct_rig(root, Config(refine=False), RigOptions(workers=1))
    return root, sim


def _copy(rig, tmp_path) -> Path:
    copy = tmp_path / "rig1"
    shutil.copytree(rig[0], copy)
    shutil.copy(rig[0].with_name("rig1.groundtruth.json"), tmp_path)
    return copy


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _page_data(page: Path) -> dict:
    return json.loads(re.search(r'<script type="application/json" id="mvm-data">(.*?)</script>',
                                page.read_text(), re.S).group(1))


def _array(values) -> np.ndarray:
    return np.array([[np.nan if v is None else v for v in row] for row in values], dtype=float)


@pytest.fixture(scope="module")
def page(rig):
    result = _invoke("report", rig[0])
    assert result.exit_code == 0, result.output
    path = rig[0] / "mvm" / "report.html"
    assert f"report: {path}" in result.output
    return path, _page_data(path)


# --- the math --------------------------------------------------------------------------------

def test_flexion_angles_of_known_bends():
    X = np.zeros((2, 17, 3))
    # left knee bent at a right angle, right leg straight; elbows at 60° of flexion
    X[:, 11], X[:, 13], X[:, 15] = [0.1, 0, 1], [0.1, 0, 0.5], [0.1, 0.4, 0.5]
    X[:, 12], X[:, 14], X[:, 16] = [-0.1, 0, 1], [-0.1, 0, 0.5], [-0.1, 0, 0.0]
    X[:, 5], X[:, 6] = [0.1, 0, 1.5], X[:, 12] + [0, 0.5, 0]          # the right trunk 90° off its thigh
    X[:, 7], X[:, 8] = [0.1, 0, 1.2], X[:, 6] + [0, 0, -0.3]
    bend = 0.3 * np.array([0, np.sin(np.pi / 3), -np.cos(np.pi / 3)])
    X[:, 9], X[:, 10] = X[:, 7] + bend, X[:, 8] + bend
    X[1, 15] = np.nan
    angles = flexion_angles(X[None])                                  # (1, 2, A)
    assert angles.shape == (1, 2, 6)
    np.testing.assert_allclose(angles[0, 0], [90, 0, 0, 90, 60, 60], atol=1e-9)  # L/R knee, hip, elbow
    assert np.isnan(angles[0, 1, 0]) and np.isfinite(angles[0, 1, 1:]).all()


def test_grouped_quantile_equals_numpy():
    rng = np.random.default_rng(0)
    values = rng.normal(size=500)
    values[rng.random(500) < 0.1] = np.nan
    group = rng.integers(0, 7, 500)
    median, count = rig_analysis.grouped_quantile(values, group, 8)
    p90, _ = rig_analysis.grouped_quantile(values, group, 8, 0.9)
    for g in range(7):
        v = values[(group == g) & np.isfinite(values)]
        assert count[g] == len(v)
        assert median[g] == pytest.approx(np.median(v)) and p90[g] == pytest.approx(np.quantile(v, 0.9))
    assert count[7] == 0 and np.isnan(median[7])


def test_flag_runs_rebuild_the_flags():
    flags = np.random.default_rng(1).choice([MISSING, OBSERVED, INTERPOLATED, INFERRED], (40, 17), p=[.1, .7, .1, .1])
    runs = rig_analysis.flag_runs(flags)
    rebuilt = np.full(flags.shape, -1)
    for j, start, stop, flag in runs:
        assert (rebuilt[start:stop, j] == -1).all()
        rebuilt[start:stop, j] = flag
    np.testing.assert_array_equal(rebuilt, flags)
    assert (runs[1:, 3] != runs[:-1, 3])[runs[1:, 0] == runs[:-1, 0]].all()   # maximal runs


def test_member_detections_follow_file_order():
    det_instant = np.array([0, 0, 1, 0, 1, 1])
    det_view = np.array([0, 0, 0, 1, 1, 1])
    members = np.array([[1, 0], [0, 1], [2, -1]])
    found = rig_analysis.member_detections(members, np.array([0, 1, 1]), det_instant, det_view)
    np.testing.assert_array_equal(found, [[1, 3], [2, 5], [-1, -1]])      # member 2 of camera 0 at 1: none
    huge = rig_analysis.member_detections(np.array([[0, 2**63 - 1]]), np.array([1]), det_instant, det_view)
    np.testing.assert_array_equal(huge, [[2, -1]])                      # a member past int64's end: none


# --- the page ----------------------------------------------------------------------------------

def test_page_has_every_instant_and_track(rig, page):
    root, _ = rig
    path, data = page
    lines = [json.loads(line) for line in (root / "mvm" / "poses3d.jsonl").read_text().splitlines()]
    recap = json.loads((root / "mvm" / "recap.json").read_text())
    view = data["view"]
    assert [i["frame"] for i in view["instants"]] == [line["frame"] for line in lines]
    assert len(view["instants"]) == recap["instants"]
    assert [len(i["persons"]) for i in view["instants"]] == [len(line["persons"]) for line in lines]
    assert len(data["figures"]["tracks"]) == recap["tracks"] == len({p["id"] for ln in lines for p in ln["persons"]})
    assert len(view["frustums"]) == 4 and [c["name"] for c in view["camera_labels"]] == ["cam_01", "cam_02",
                                                                                         "cam_03", "cam_04"]
    html = path.read_text()
    for section in ("recap", "view3d", "tracks", "cameras", "angles"):
        assert f'<section id="{section}">' in html
    assert html.count('<svg class="timeline"') == recap["tracks"]
    assert "http://" not in html.replace("http://www.w3.org/2000/svg", "")          # offline
    assert json.loads((root / "mvm" / ".mvm-output").read_text()).count("report.html") == 1


def test_recap_section_shows_recap_json(rig, page):
    root, _ = rig
    recap = json.loads((root / "mvm" / "recap.json").read_text())
    html = page[0].read_text()
    table = re.search(r'<table class="small" id="recap-keypoints">(.*?)</table>', html, re.S).group(1)
    rows = re.findall(r"<tr><td>([a-z_]+)</td><td>([^<]*)</td><td>([^<]*)</td>((?:<td>[^<]*</td>)*)</tr>", table)
    assert [r[0] for r in rows] == recap["keypoints"]
    for j, (_, error, views, excluded) in enumerate(rows):
        assert float(error) == pytest.approx(recap["error_per_keypoint_px"][j], abs=0.006)
        assert float(views) == pytest.approx(recap["views_per_keypoint"][j], abs=0.006)
        cells = re.findall(r"<td>([^<]*)</td>", excluded)
        assert [float(c) for c in cells] == pytest.approx(
            [recap["excluded_per_camera"][n][j] for n in recap["excluded_per_camera"]], abs=0.006)
    cameras = re.search(r'<table class="small" id="camera-errors">(.*?)</table>', html, re.S).group(1)
    for name, share in recap["excluded_overall_per_camera"].items():
        assert re.search(rf"{name}</td>(?:<td>[^<]*</td>){{3}}<td>{share:.3f}</td>", cameras)


def test_joint_angles_match_the_true_bodies(rig, page):
    root, sim = rig
    _, data = page
    poses = read_rig_poses3d(root / "mvm" / "poses3d.jsonl")
    names = data["figures"]["angle_names"]
    assert names == ["left knee", "right knee", "left hip", "right hip", "left elbow", "right elbow"]
    chains = {"knee": (11, 13, 15), "hip": (5, 11, 13), "elbow": (5, 7, 9)}
    index = np.array([[c + (1 if side == "right" else 0) for c in chains[n.split()[1]]] for n in names
                      for side in [n.split()[0]]])

    def independent(X):                        # 180° minus the angle at the middle joint, by atan2
        u, v = X[..., index[:, 0], :] - X[..., index[:, 1], :], X[..., index[:, 2], :] - X[..., index[:, 1], :]
        return 180 - np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), (u * v).sum(-1)))

    errors = []
    for track, found in data["figures"]["angles"].items():
        rows = poses.track == int(track)
        degrees, flags = _array(found["degrees"]), np.array(found["flags"])
        assert found["frames"] == poses.frames[poses.instant[rows]].tolist()
        np.testing.assert_allclose(degrees, independent(poses.X[rows]), atol=0.006)   # the page's own numbers
        truth = sim.poses3d[np.searchsorted(sim.instants, np.array(found["frames"]) + sim.offsets[0])]  # (L, G, 17, 3)
        diff = np.abs(independent(truth) - degrees[:, None])                          # (L, G, A)
        person = np.nanargmin(np.nanmean(diff, axis=(0, 2)))
        errors.append(diff[:, person][flags == OBSERVED])
    errors = np.concatenate(errors)
    assert len(data["figures"]["angles"]) == 3 and np.isfinite(errors).sum() > 500
    assert np.nanmedian(errors) < 4.0 and np.nanpercentile(errors, 90) < 10.0        # degrees


def _independent_camera_errors(root: Path, sim) -> dict[str, np.ndarray]:
    """Every matched keypoint's error, from the pose files undistorted by OpenCV and the written
    3D joints projected by the true pinhole cameras (no mvm code but the file reader)."""
    poses = read_rig_poses3d(root / "mvm" / "poses3d.jsonl")
    cams = sim.calibration.cameras
    out = {}
    for v, name in enumerate(cams.names):
        document = json.loads((root / "pose" / f"{name}.json").read_text())
        per_frame = {}
        frame_of = {im["id"]: int(Path(im["file_name"]).stem) for im in document["images"]}
        for a in document["annotations"]:
            per_frame.setdefault(frame_of[a["image_id"]], []).append(np.array(a["keypoints"], float).reshape(17, 3))
        errors = []
        for q in np.flatnonzero(poses.members[:, poses.cameras.index(name)] >= 0):
            frame = poses.frames[poses.instant[q]] - int(sim.sync_offsets[v])
            kp = per_frame[frame][poses.members[q, poses.cameras.index(name)]]
            xy = cv2.undistortPoints(kp[:, None, :2], cams.K[v], sim.calibration.distortions[v], P=cams.K[v])[:, 0]
            x = (cams.K[v] @ (cams.R[v] @ poses.X[q].T + cams.t[v][:, None])).T
            e = np.linalg.norm(x[:, :2] / x[:, 2:] - xy, axis=1)
            errors.append(e[(kp[:, 2] > 0) & (poses.flags[q] == OBSERVED)])
        out[name] = np.concatenate(errors)
    return out


def test_camera_errors_equal_an_independent_computation(rig, page):
    root, sim = rig
    _, data = page
    found = data["figures"]["camera_error"]
    truth = _independent_camera_errors(root, sim)
    for v, name in enumerate(data["figures"]["cameras"]):
        assert found["overall_keypoints"][v] == len(truth[name])
        assert found["overall_median_px"][v] == pytest.approx(np.median(truth[name]), abs=2e-3)
        assert found["overall_p90_px"][v] == pytest.approx(np.quantile(truth[name], 0.9), abs=2e-3)


def test_camera_error_over_time_shows_the_fault_where_it_was(rig, page):
    root, sim = rig
    _, data = page
    found = data["figures"]["camera_error"]
    frames = np.array(found["frames"])
    median = _array(found["median_px"])                                   # (T, V): one bin per instant
    assert len(frames) == len(data["view"]["instants"])
    shift = int(sim.sync_offsets[2])                                      # cam_03's frames, reference numbering
    window = np.isin(frames, np.array(FAULT) + shift)
    faulty = median[window, 2]
    assert np.nanmin(faulty) > 0.8 * FAULT_PX and np.isfinite(faulty).sum() >= 5
    assert np.nanmax(median[~window, 2]) < 0.3 * FAULT_PX                # nowhere else
    assert np.nanmax(median[:, [0, 1, 3]]) < 0.3 * FAULT_PX              # the other cameras: unharmed


def test_viewer_slides_over_the_instants(page):
    node = shutil.which("node")
    if node is None:
        pytest.skip("needs Node.js to run the page's script")
    harness = Path(__file__).with_name("viewer_harness.js")
    instants = page[1]["view"]["instants"]
    busiest = max(range(len(instants)), key=lambda i: len(instants[i]["persons"]))
    done = subprocess.run([node, str(harness), str(page[0]), str(busiest)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    state = json.loads(done.stdout)
    assert state["errors"] == [] and state["status"]["data-state"] == "rendered"
    assert state["max"] == str(len(instants) - 1) and state["status"]["data-instant"] == str(busiest)
    assert int(state["status"]["data-segments"]) >= 16 * len(instants[busiest]["persons"]) == 16 * 3
    assert state["label"] == f"frame {instants[busiest]['frame']} ({busiest + 1} / {len(instants)})"


def test_viewer_still_draws_a_scene_page(tmp_path):
    """The viewer the scene report shares: a scene's page (no instants, no slider) renders as before."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("needs Node.js to run the page's script")
    from test_report import make_scene

    from mvm.report import write_report

    make_scene(tmp_path / "scene", people=3, frames=20)
    page = write_report(tmp_path / "scene", frames=0)
    done = subprocess.run([node, str(Path(__file__).with_name("viewer_harness.js")), str(page)], capture_output=True,
                          text=True, timeout=60)
    state = json.loads(done.stdout)
    assert state["errors"] == [] and state["status"]["data-state"] == "rendered"
    assert "data-instant" not in state["status"] and int(state["status"]["data-segments"]) >= 3 * 16


# --- the overlays ------------------------------------------------------------------------------

def _render_videos(root: Path, sim, cameras: list[int]) -> tuple[int, int]:
    """Plain videos of the given cameras at VIDEO_SCALE of their image size, one frame per frame."""
    (root / "videos").mkdir(exist_ok=True)
    W, H = (np.round(sim.calibration.cameras.size[0] * VIDEO_SCALE)).astype(int)
    for v in cameras:
        writer = cv2.VideoWriter(str(root / "videos" / f"{sim.calibration.cameras.names[v]}.mp4"),
                                 cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (int(W), int(H)))
        for _ in range(sim.frames):
            writer.write(np.full((H, W, 3), BACKGROUND, np.uint8))
        writer.release()
    return int(W), int(H)


def _true_pixels(sim, v: int, frame: int) -> np.ndarray:
    """The true joints of every person at camera ``v``'s ``frame``, through its lens, at VIDEO_SCALE: (G, 17, 2)."""
    cams = sim.calibration.cameras
    instant = np.searchsorted(sim.instants, frame + sim.offsets[v])
    X = sim.poses3d[instant].reshape(-1, 3)
    uv = cv2.projectPoints(X, cv2.Rodrigues(cams.R[v])[0], cams.t[v], cams.K[v], sim.calibration.distortions[v])[0]
    return VIDEO_SCALE * uv.reshape(-1, 17, 2)


def test_overlay_draws_on_the_true_joints(rig, tmp_path):
    root = _copy(rig, tmp_path)
    sim = rig[1]
    W, H = _render_videos(root, sim, [0, 1, 2])
    result = _invoke("overlay", root)
    assert result.exit_code == 0, result.output
    assert "no video for camera cam_04" in result.output and "skipped" in result.output
    written = sorted(p.name for p in (root / "mvm" / "overlay").glob("*.mp4"))
    assert written == ["cam_01.mp4", "cam_02.mp4", "cam_03.mp4"]
    rng = np.random.default_rng(0)
    for v in (0, 1):                                       # offsets 0 and +3: the instant each frame shows
        capture = cv2.VideoCapture(str(root / "mvm" / "overlay" / f"cam_0{v + 1}.mp4"))
        images = []
        while True:
            ok, image = capture.read()
            if not ok:
                break
            images.append(image.astype(int))
        assert len(images) == sim.frames and images[0].shape == (H, W, 3)
        hits, shifted_hits, total, background = 0, 0, 0, []
        for frame in range(5, sim.frames - 5, 4):
            drawn = np.abs(images[frame] - BACKGROUND).max(-1) > 40                        # (H, W)
            for uv, wrong in ((_true_pixels(sim, v, frame), False), (_true_pixels(sim, v, frame - 3), True)):
                uv = np.round(uv.reshape(-1, 2)).astype(int)
                inside = (uv[:, 0] >= 1) & (uv[:, 0] < W - 1) & (uv[:, 1] >= 1) & (uv[:, 1] < H - 1)
                near = np.array([drawn[y - 1:y + 2, x - 1:x + 2].any() for x, y in uv[inside]])
                if wrong:
                    shifted_hits += near.sum()
                else:
                    hits, total = hits + near.sum(), total + inside.sum()
            people = _true_pixels(sim, v, frame)
            low, high = people.min((0, 1)) - 15, people.max((0, 1)) + 15
            points = rng.uniform([0, 0], [W, H], (200, 2)).astype(int)
            away = ~((points >= low) & (points <= high)).all(1)
            background.append(~drawn[points[away, 1], points[away, 0]])
        assert total > 300 and hits / total > 0.9
        assert np.concatenate(background).mean() > 0.99                    # nothing drawn away from the people
        if v == 1:                                                         # the frame 3 instants earlier fits less
            assert shifted_hits < hits


# --- bad inputs --------------------------------------------------------------------------------

def _one_line_2(result, *words):
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("mvm: error: "), result.output
    assert "Traceback" not in result.output
    for w in words:
        assert w in lines[0], lines[0]


def test_rig_without_output_is_one_line(rig, tmp_path):
    root = tmp_path / "bare"
    root.mkdir()
    shutil.copy(rig[0] / "Calib.toml", root)
    shutil.copytree(rig[0] / "pose", root / "pose")
    _one_line_2(_invoke("report", root), "poses3d.jsonl", "mvm rig reconstruct")
    _one_line_2(_invoke("overlay", root), "poses3d.jsonl", "mvm rig reconstruct")
    assert not (root / "mvm").exists()
    (root / "Calib.toml").unlink()                                         # nor a calibration: the same line
    for command in ("report", "overlay"):
        _one_line_2(_invoke(command, root), "poses3d.jsonl: missing: reconstruct the rig first")


def test_stale_output_is_refused(rig, tmp_path):
    root = _copy(rig, tmp_path)
    (root / "mvm" / "report.html").unlink()
    pose = root / "pose" / "cam_02.json"
    document = json.loads(pose.read_text())
    document["annotations"][0]["keypoints"][0] += 3.0
    pose.write_text(json.dumps(document))
    for command in ("report", "overlay"):                                 # the rig's own calibration: no --calib
        _one_line_2(_invoke(command, root), "out of date", "pose changed since the rig reconstruction",
                    f"run `mvm rig reconstruct {root}` first")
    assert not (root / "mvm" / "report.html").exists()


def test_changed_sync_is_refused_and_makes_the_set_again(rig, tmp_path):
    root = _copy(rig, tmp_path)
    write_sync_toml(root / "sync.toml", {"cam_01": 0, "cam_02": 3, "cam_03": -1, "cam_04": 1})
    _one_line_2(_invoke("report", root), "out of date", "sync.toml changed")
    result = _invoke("rig", "reconstruct", root, "--no-refine", "--workers", 1)
    assert result.exit_code == 0 and "output set: made: sync.toml changed since the rig reconstruction" in result.output
    assert not (root / "mvm" / "report.html").exists()                     # the new set replaced the page
    assert _invoke("report", root).exit_code == 0


def test_undecodable_video_is_refused_before_writing(rig, tmp_path):
    root = _copy(rig, tmp_path)
    _render_videos(root, rig[1], [0])
    (root / "videos" / "cam_02.mp4").write_bytes(b"\x00not a video" * 100)
    _one_line_2(_invoke("overlay", root), "cam_02.mp4", "cannot be decoded")
    assert not (root / "mvm" / "overlay").exists()
    writer = cv2.VideoWriter(str(root / "videos" / "cam_02.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (64, 64))
    writer.write(np.zeros((64, 64, 3), np.uint8))
    writer.release()
    _one_line_2(_invoke("overlay", root), "cam_02.mp4", "frames of 64×64 px", "1920×1080")
    assert not (root / "mvm" / "overlay").exists()
    _one_line_2(_invoke("overlay", root, "-o", tmp_path / "one.mp4"), "one video per camera")
    shutil.rmtree(root / "videos")
    _one_line_2(_invoke("overlay", root), "no video of any camera")


def test_broken_poses3d_line_is_named(rig, tmp_path):
    root = _copy(rig, tmp_path)
    path = root / "mvm" / "poses3d.jsonl"
    lines = path.read_text().splitlines()
    lines[4] = lines[4].replace('"keypoints3d":[[', '"keypoints3d":[[1,', 1)
    path.write_text("\n".join(lines) + "\n")
    _one_line_2(_invoke("report", root), "poses3d.jsonl", "line 5", "keypoints3d")


def test_report_inside_an_input_is_refused(rig, tmp_path):
    root = _copy(rig, tmp_path)
    _one_line_2(_invoke("report", root, "-o", root / "pose" / "page.html"), "lies inside the input folder")
    _one_line_2(_invoke("report", root, "--calib", root / "Calib.toml", "-o", root / "Calib.toml"), "")
    scene_calib = _invoke("report", root, "--calib", root / "Calib.toml", "-o", tmp_path / "page.html")
    assert scene_calib.exit_code == 0 and (tmp_path / "page.html").is_file()
    assert read_calib_toml(root / "Calib.toml").cameras.names[0] == "cam_01"


def test_reconstruction_without_persons_gives_a_page(rig, tmp_path):
    root = _copy(rig, tmp_path)
    path = root / "mvm" / "poses3d.jsonl"
    lines = [{**json.loads(line), "persons": []} for line in path.read_text().splitlines()]
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    result = _invoke("report", root)
    assert result.exit_code == 0, result.output
    data = _page_data(root / "mvm" / "report.html")
    assert len(data["view"]["instants"]) == len(lines) and data["figures"]["tracks"] == []
    assert all(v is None for v in data["figures"]["camera_error"]["overall_median_px"])


def test_a_page_added_to_the_set_goes_with_it(tmp_path):
    """What is added to an output set is listed in its marker: the set can still be replaced, also
    with the temporaries a killed writer of a listed entry left; anything else in it is refused."""
    from mvm.io.files import OutputError, atomic_write_text
    from mvm.io.outputs import add_to_output_set, atomic_replace_dir, check_replaceable

    folder = tmp_path / "out"
    atomic_replace_dir(lambda f: (f / "a.json").write_text("{}"), folder)
    add_to_output_set(folder, "page.html", lambda p: atomic_write_text(p, "<html>"))
    assert json.loads((folder / ".mvm-output").read_text()) == ["a.json", "page.html"]
    (folder / ".page.html.mvm-tmp-x1y2.tmp").write_text("partial")      # a killed writer's
    check_replaceable(folder)
    (folder / ".notes.mvm-tmp-x1y2.tmp").write_text("someone else's")
    with pytest.raises(OutputError, match="notes"):
        check_replaceable(folder)
    (folder / ".notes.mvm-tmp-x1y2.tmp").unlink()
    atomic_replace_dir(lambda f: (f / "a.json").write_text("[]"), folder)
    assert sorted(p.name for p in folder.iterdir()) == [".mvm-output", "a.json"]


# --- ground truth --------------------------------------------------------------------------------

def test_truth_section_of_a_simulated_rig(rig, page):
    root, sim = rig
    _, data = page
    truth = data["figures"]["truth"]
    assert truth["scale"] == 1.0 and max(truth["camera_residual_m"]) == 0.0           # the true calibration
    poses = read_rig_poses3d(root / "mvm" / "poses3d.jsonl")
    true = sim.poses3d[np.searchsorted(sim.instants, poses.frames + sim.offsets[0])]  # (T, G, 17, 3)
    assert len(data["view"]["instants"][20]["truth"]) == sim.poses3d.shape[1]
    for track, found in truth["tracks"].items():
        rows = poses.track == int(track)
        d = np.linalg.norm(poses.X[rows][:, None] - true[poses.instant[rows]], axis=-1)   # (L, G, 17)
        person = int(np.argmin(np.nanmean(d, axis=(0, 2))))
        assert found["true_person"] == person
        observed = d[:, person][poses.flags[rows] == OBSERVED]
        assert found["mpjpe_m"] == pytest.approx(observed.mean(), abs=1e-5)
    assert sorted(t["true_person"] for t in truth["tracks"].values()) == [0, 1, 2]
    assert truth["mpjpe_m"]["observed"] < 0.03                                        # metres


def _moved(calibration, scale: float, R0: np.ndarray, t0: np.ndarray):
    """The calibration of the same cameras in a world moved by ``x' = scale R0 x + t0``."""
    from mvm.io.calib_toml import RigCalibration

    c = calibration.cameras
    R = c.R @ R0.T
    t = scale * c.t - np.einsum("vij,j->vi", R, t0)
    return RigCalibration(dataclasses.replace(c, R=R, t=t))


def test_truth_through_a_calibration_in_another_frame(rig, page, tmp_path):
    """A calibration in its own frame and units (as from the people): the similarity of the camera
    centres brings the estimate back, and it scores as with the true calibration."""
    from mvm.io.calib_toml import write_calib_toml

    root = _copy(rig, tmp_path)
    R0 = cv2.Rodrigues(np.array([0.3, -0.2, 1.1]))[0]
    moved = tmp_path / "moved.toml"
    write_calib_toml(moved, _moved(rig[1].calibration, 1.7, R0, np.array([2.0, -1.0, 0.5])))
    result = _invoke("rig", "reconstruct", root, "--calib", moved, "--no-refine", "--workers", 1)
    assert result.exit_code == 0, result.output
    result = _invoke("report", root)
    assert result.exit_code == 0, result.output
    truth = _page_data(root / "mvm" / "report.html")["figures"]["truth"]
    assert truth["scale"] == pytest.approx(1 / 1.7, rel=1e-6) and max(truth["camera_residual_m"]) < 1e-6
    before = page[1]["figures"]["truth"]["mpjpe_m"]["observed"]
    assert truth["mpjpe_m"]["observed"] == pytest.approx(before, rel=0.2, abs=0.002)


def test_pages_written_into_the_set_by_name_go_with_it(rig, tmp_path):
    root = _copy(rig, tmp_path)
    assert _invoke("report", root, "-o", root / "mvm" / "second.html").exit_code == 0
    assert "second.html" in json.loads((root / "mvm" / ".mvm-output").read_text())
    result = _invoke("rig", "reconstruct", root, "--no-refine", "--workers", 1, "--force")
    assert result.exit_code == 0, result.output
    assert not (root / "mvm" / "second.html").exists()


def test_keypoint_errors_do_not_depend_on_the_block(rig):
    from mvm.stages.view import ViewJob, load_rig_view

    data = load_rig_view(ViewJob(rig[0]), workers=1)
    p = data.poses
    args = (p.X, p.flags, data.detection, data.detections.keypoints, data.calibration.cameras.P)
    np.testing.assert_array_equal(rig_analysis.keypoint_errors(*args, block=7), rig_analysis.keypoint_errors(*args))


@pytest.mark.parametrize("change", [{"joint_flags": [1, 2]}, {"excluded_per_camera": [1]},
                                    {"excluded_per_camera": {"cam_01": 3}}, {"keypoints": 5},
                                    {"excluded_overall_per_camera": [0.1]}, {"options": {"frame_rate": "x"}},
                                    {"sync_offsets": [1]}, {"instants": "many"}])
def test_a_recap_of_the_wrong_shape_is_one_line_or_read(rig, tmp_path, change):
    root = _copy(rig, tmp_path)
    path = root / "mvm" / "recap.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), **change}))
    result = _invoke("report", root)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    if "sync_offsets" in change:                                          # the staleness check's line
        _one_line_2(result, "out of date", "sync.toml")
    elif isinstance(next(iter(change.values())), list) or change.get("keypoints") == 5:   # a wrong container
        _one_line_2(result, "recap.json", next(iter(change)))
    else:                                                                 # a wrong value inside is read
        assert result.exit_code == 0, result.output


def test_markup_in_the_recap_is_text_on_the_page(rig, tmp_path):
    """Names that recap.json gives (its joint flags, its keypoints) are shown as text: markup in
    them never becomes part of the page (an input file never runs code in the browser)."""
    root = _copy(rig, tmp_path)
    path = root / "mvm" / "recap.json"
    recap = json.loads(path.read_text())
    hostile = '<img src=x onerror="alert(1)">'
    recap["joint_flags"] = {**recap["joint_flags"], hostile: 0.5}
    recap["keypoints"] = [hostile] + recap["keypoints"][1:]
    path.write_text(json.dumps(recap))
    result = _invoke("report", root)
    assert result.exit_code == 0, result.output
    html = (root / "mvm" / "report.html").read_text()
    assert "<img" not in html and html.count("&lt;img src=x onerror=&quot;alert(1)&quot;&gt;") == 2



def test_a_rig_reconstructed_with_a_calibration_kept_elsewhere(rig, tmp_path):
    """A rig reconstructed with a calibration kept elsewhere (and none of its own): the page and
    the overlays read that calibration, named in the set's record, and check their output
    location against it: an overlay folder over it is refused, the calibration kept."""
    root = _copy(rig, tmp_path)
    elsewhere = tmp_path / "calibrations" / "Calib.toml"
    elsewhere.parent.mkdir()
    shutil.move(root / "Calib.toml", elsewhere)
    before = elsewhere.read_bytes()
    reconstruct_rig(root, Config(refine=False), RigOptions(workers=1), calib=elsewhere)
    result = _invoke("report", root)
    assert result.exit_code == 0, result.output
    _one_line_2(_invoke("overlay", root, "-o", tmp_path), "contains the input", str(elsewhere))
    assert elsewhere.read_bytes() == before
