"""What keeping frames by camera motion gives and costs, against keeping every frame.

    python benchmarks/frame_selection.py [--quick] [--frames 300] [--people 6] [--paths real,stop]
                                         [--trajectory FILE] [--cameras both|sfm|true] [--out DIR]

Videos: a simulated mannequin scene (``SimConfig.preset("realistic")``, 640×360, 30 frames/s)
rendered frame by frame (:func:`mvm.sim.mannequin_video.render_frames`) into an mp4, its camera
touring the crowd along

* ``real path``: a real hand-held camera path (``--trajectory``, by default the first file of
  ``../shared/data/camera_trajectories``; its speed profile, bent onto a 90° arc);
* ``slow, stop, fast``: a path written for the test: 40 % of the time slow, 30 % stopped, 30 %
  fast (the camera's speed 1 : 0 : 4).

The 2D poses are the simulator's (the realistic detector: noise, dropped joints, swaps, false
poses), imported by frame name. Each video goes through ``mvm run``'s stages one by one
(frames, SfM with pycolmap, import, reconstruction) three times: every frame (``select = "all"``),
the default selection by camera motion, and as many frames spread evenly in time
(``max_frames``); then the three again with the true cameras instead of SfM, to see the
reconstruction's own accuracy on the kept frames. Printed per run: frames kept, the
wall and CPU seconds of every stage, frames registered by SfM, persons, pairwise precision /
recall of the 2D poses' grouping, MPJPE / PA-MPJPE (mm; with SfM, after the similarity that
puts the SfM camera centres on the true ones).

``--quick``: 150 frames, one path.
"""
from __future__ import annotations

import argparse
import json
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TRAJECTORIES = Path(__file__).resolve().parents[2] / "shared" / "data" / "camera_trajectories"
FPS = 30.0


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime + children.ru_utime + children.ru_stime


def stop_path(path: Path, seconds: float) -> Path:
    """A RealEstate10K camera file: along x, slow for 40 % of ``seconds``, still for 30 %,
    four times as fast for the last 30 % (one line per frame at :data:`FPS`)."""
    t = np.arange(int(seconds * FPS) + 1) / FPS
    speed = np.where(t < 0.4 * seconds, 1.0, np.where(t < 0.7 * seconds, 0.0, 4.0))
    x = np.concatenate([[0.0], np.cumsum(speed[1:] / FPS)])
    lines = ["https://example.org/slow-stop-fast"]
    for ti, xi in zip(t, x):
        pose = [1, 0, 0, -xi, 0, 1, 0, 0, 0, 0, 1, 0]
        lines.append(" ".join([str(int(round(ti * 1e6))), "0.8", "1.4222", "0.5", "0.5", "0", "0"]
                              + [f"{v:.9f}" for v in pose]))
    path.write_text("\n".join(lines) + "\n")
    return path


def make_video(out: Path, trajectory: Path, frames: int, people: int, seed: int):
    """Simulate, render and encode one tour -> (video, detections file, scene, truth, true model)."""
    import cv2

    from mvm.io.ground_truth import write_simulation
    from mvm.sim.mannequin_video import render_frames
    from mvm.sim.simulate import SimConfig, simulate

    sim = SimConfig.preset("realistic", people=people, frames=frames, arc_deg=90.0, image_width=640,
                           image_height=360, focal_px=500.0, trajectory=str(trajectory), seed=seed)
    scene, truth = simulate(sim)
    write_simulation(out / "truth", scene, truth, sim)
    paths = render_frames(out / "render", scene.cameras, truth.poses3d, seed)
    video = out / "tour.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (640, 360))
    for p in paths:
        writer.write(cv2.imread(str(p)))
    writer.release()
    shutil.rmtree(out / "render")
    results = []
    poses = scene.poses
    for k in range(len(poses.keypoints)):
        kp = np.nan_to_num(poses.keypoints[k]).copy()
        results.append({"image_id": scene.cameras.names[poses.view[k]], "category_id": 1,
                        "keypoints": kp.reshape(-1).round(3).tolist(), "score": float(poses.score[k])})
    detections = out / "detections.json"
    detections.write_text(json.dumps(results))
    return video, detections, scene, truth, out / "truth" / "sparse"


def true_person(poses, cameras, sim_scene, truth) -> np.ndarray:
    """The true person (-1: a false pose) of every 2D pose of a reconstructed scene, found by its
    keypoints among the simulator's poses of the same frame."""
    by_frame: dict[str, np.ndarray] = {}
    for name in set(sim_scene.cameras.names):
        by_frame[name] = np.flatnonzero(np.array(sim_scene.cameras.names)[sim_scene.poses.view] == name)
    sim_xy = np.nan_to_num(sim_scene.poses.keypoints[..., :2])
    out = np.full(len(poses.keypoints), -1)
    for i in range(len(poses.keypoints)):
        candidates = by_frame[cameras.names[poses.view[i]]]
        gap = np.abs(sim_xy[candidates] - np.nan_to_num(poses.keypoints[i, :, :2])).max(axis=(1, 2))
        out[i] = truth.person[candidates[np.argmin(gap)]]
    return out


def evaluate(scene_dir: Path, sim_scene, truth, aligned_by_cameras: bool) -> dict:
    from mvm.io.scene_dir import read_poses3d, read_scene
    from mvm.metrics.poses import match_persons, matching_precision_recall, pose_errors, similarity_transform

    scene = read_scene(scene_dir)
    persons = read_poses3d(scene_dir / "mvm" / "poses3d.json", scene.poses)
    X = persons.keypoints3d
    if aligned_by_cameras:
        index = [sim_scene.cameras.names.index(n) for n in scene.cameras.names]
        s, R, t = similarity_transform(scene.cameras.centers, sim_scene.cameras.centers[index])
        X = s * X @ R.T + t
    precision, recall = matching_precision_recall(persons.members, true_person(scene.poses, scene.cameras,
                                                                                  sim_scene, truth))
    pairs = match_persons(X, truth.poses3d, 0.5)
    errors = pose_errors(X, truth.poses3d, pairs)
    return {"registered": len(scene.cameras), "poses": len(scene.poses.keypoints), "persons": len(persons),
            "found": len(pairs), "precision": precision, "recall": recall,
            "mpjpe_mm": 1000 * errors["mpjpe"], "pa_mpjpe_mm": 1000 * errors["pa_mpjpe"]}


def run(video: Path, detections: Path, scene_dir: Path, options, cameras: Path | None) -> dict:
    """The stages of ``mvm run`` one by one, timed: frames, SfM (or the true cameras), import,
    reconstruction (no metric scale: the world stays SfM's, aligned afterwards)."""
    from mvm.stages import Job, SceneOptions, run_stage, scene_stage
    from mvm.video.detect import DetectOptions, detect_scene
    from mvm.video.frames import extract_frames
    from mvm.video.sfm import SfmOptions, import_colmap, run_sfm

    timing = {}

    def timed(name, call):
        wall, cpu = time.perf_counter(), cpu_seconds()
        value = call()
        timing[name] = (time.perf_counter() - wall, cpu_seconds() - cpu)
        return value

    index = timed("frames", lambda: extract_frames(video, scene_dir, options))
    if cameras is None:
        timed("sfm", lambda: run_sfm(scene_dir, SfmOptions(camera_model="SIMPLE_PINHOLE", max_features=2048)))
    else:
        timed("sfm", lambda: import_colmap(cameras, scene_dir))
    timed("detect", lambda: detect_scene(scene_dir, detections, None, "coco-results",
                                         DetectOptions(detector="import", appearance="colour")))
    timed("reconstruct", lambda: run_stage(scene_stage("reconstruct"),
                                                Job(scene_dir, SceneOptions(metric_scale=False))))
    return {"kept": len(index.names), "candidates": index.selection.get("candidates"), "timing": timing}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--people", type=int, default=6)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--paths", default="real,stop", help="camera paths: real, stop (comma-separated)")
    parser.add_argument("--trajectory", type=Path, default=None, help="the real path's camera file")
    parser.add_argument("--cameras", choices=("both", "sfm", "true"), default="both",
                        help="SfM, the true cameras, or both")
    parser.add_argument("--out", type=Path, default=None, help="keep the videos and scenes here")
    args = parser.parse_args(argv)
    from mvm.video.frames import FrameOptions

    frames = 150 if args.quick else args.frames
    root = args.out or Path(tempfile.mkdtemp(prefix="mvm-frame-selection-"))
    files = [args.trajectory] if args.trajectory else sorted(TRAJECTORIES.glob("*.txt")) if TRAJECTORIES.is_dir() \
        else []
    wanted = {"stop"} if args.quick else set(args.paths.split(","))
    if "real" in wanted and not files:
        print(f"no camera file in {TRAJECTORIES} (give --trajectory): the real path is left out", file=sys.stderr)
    paths = ([("real path", files[0])] if files and "real" in wanted else []) + \
        ([("slow, stop, fast", None)] if "stop" in wanted else [])
    rows = []
    for label, trajectory in paths:
        out = root / label.replace(", ", "-").replace(" ", "-")
        out.mkdir(parents=True, exist_ok=True)
        trajectory = trajectory or stop_path(out / "path.txt", frames / FPS)
        video, detections, sim_scene, truth, model = make_video(out, trajectory, frames, args.people, args.seed)
        kept = {}
        sources = {"both": (None, model), "sfm": (None,), "true": (model,)}[args.cameras]
        for select, cameras in [(s, c) for c in sources for s in ("all", "motion", "uniform")]:
            name = f"{select}-{'true' if cameras else 'sfm'}"
            options = FrameOptions(max_frames=kept["motion"]) if select == "uniform" else FrameOptions(select=select)
            result = run(video, detections, out / name, options, cameras)
            kept[select] = result["kept"]
            result.update(evaluate(out / name, sim_scene, truth, aligned_by_cameras=cameras is None))
            rows.append((label, select, "true" if cameras else "SfM", result))
            print(json.dumps({"path": label, "select": select, "cameras": "true" if cameras else "SfM",
                              **result}), file=sys.stderr, flush=True)
    print(f"{frames} frames at {FPS:g} frames/s, {args.people} people (realistic detector), 640×360; seconds: "
          "wall (CPU)")
    print("| path | frames kept | cameras | frames s | SfM s | reconstruct s | registered | persons (true) "
          "| precision | recall | MPJPE mm | PA-MPJPE mm |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for label, select, cams, r in rows:
        t = r["timing"]
        cell = lambda k, t=t: f"{t[k][0]:.1f} ({t[k][1]:.1f})"  # noqa: E731
        kept = f"{r['kept']} of {frames} ({select})"
        print(f"| {label} | {kept} | {cams} | {cell('frames')} | {cell('sfm') if cams == 'SfM' else '—'} | "
              f"{cell('reconstruct')} | {r['registered']} | {r['found']} / {r['persons']} ({args.people}) | "
              f"{r['precision']:.4f} | {r['recall']:.4f} | {r['mpjpe_mm']:.1f} | {r['pa_mpjpe_mm']:.1f} |")
    if args.out is None:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
