"""``mvm simulate``, ``mvm demo`` and ``mvm bench``: simulated scenes with ground truth."""
from __future__ import annotations

import time
from pathlib import Path

import click

from mvm.cli.common import (
    Number,
    OutputPath,
    command,
    config_options,
    fmt,
    measure_table,
    print_table,
    read_config,
    refused,
    say,
    stage_progress,
)
from mvm.cli.setting_options import setting_option
from mvm.io.layout import SceneLayout

SIM = "mvm.sim.simulate:SimConfig"


def scene_options(f):
    """``--people``, ``--frames``, ``--arc`` and ``--seed`` of a simulated scene."""
    for option in reversed([
        # The simulated scenes the commands make are bounded tighter than SimConfig's.
        setting_option(SIM, "people", type=Number(int, ge=1, le=30)),
        setting_option(SIM, "frames", type=Number(int, ge=20, le=3600)),
        setting_option(SIM, "arc_deg", "--arc", type=Number(float, ge=5, le=180)),
        setting_option(SIM, "seed"),
    ]):
        f = option(f)
    return f


def read_sim(config_path: str | None, preset: str | None = None, **flags):
    """The simulated scene's :class:`~mvm.sim.simulate.SimConfig`: the ``preset`` (none: the
    defaults), the ``[simulate]`` table of the settings file over it, the command's options
    (``flags``; one left at None keeps the file's value) over both."""
    from mvm.settings.tables import load_settings
    from mvm.sim.simulate import SimConfig

    flags = {k: v for k, v in flags.items() if v is not None}
    base = SimConfig.preset(preset, **{k: flags[k] for k in ("people",) if k in flags}) if preset else SimConfig()
    return load_settings(SimConfig, "simulate", config_path, flags,
                         {k: {"arc_deg": "--arc"}.get(k, "--" + k) for k in flags}, base=base)


@command("simulate")
@click.argument("scene_dir", type=click.Path(file_okay=False))
@click.option("--preset", type=click.Choice(["clean", "precise", "realistic", "hard", "heavy", "crowd"]),
              default="realistic", show_default=True,
              help="Detector error model (noise from 0.5 % of the person's size to 3 %; 'crowd': a dense frozen "
                   "crowd of 12 people, 1080p).")
@scene_options
@click.option("--trajectory", type=click.Path(dir_okay=False, exists=True), default=None,
              help="Follow a real camera path (RealEstate10K / MannequinChallenge camera file).")
@click.option("--render", is_flag=True,
              help="Also render the frames into SCENE_DIR/frames (for mvm export and training).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="TOML settings file: its [simulate] table, over the preset (mvm config prints one).")
@click.option("--rig", is_flag=True,
              help="Simulate a camera rig instead: SCENE_DIR becomes a rig folder (Calib.toml, pose/<camera>.json) "
                   "for mvm rig synchronize / calibrate / reconstruct; the truth goes beside it.")
@click.option("--cameras", default=5, show_default=True, type=Number(int, ge=1, le=30),
              help="With --rig: cameras on a ring around the people (1-30).")
@click.option("--offsets", default=None, metavar="O1,O2,...",
              help="With --rig: each camera's frame offset (camera c's frame f shows the instant f + Oc; "
                   "mvm rig synchronize finds Oc - O1).")
@click.option("--intrinsics-only", is_flag=True,
              help="With --rig: write Calib.toml without rotations and translations (for mvm rig calibrate "
                   "--from-people); the full one goes beside the folder.")
@click.option("--videos", is_flag=True,
              help="With --rig: render each camera's video into SCENE_DIR/videos instead of writing its 2D poses "
                   "(for mvm rig detect).")
@click.option("--video-type", type=click.Choice(["mp4", "mkv"]), default="mp4", show_default=True,
              help="With --videos: the videos' file type (mkv: lossless FFV1).")
def simulate_cmd(scene_dir, preset, people, frames, arc_deg, seed, trajectory, render, config_path, rig, cameras,
                 offsets, intrinsics_only, videos, video_type):
    """Simulate a mannequin scene into SCENE_DIR; the ground truth goes beside it
    (SCENE_DIR.groundtruth.json). With --rig, a rig of cameras around moving people."""
    from mvm.io.ground_truth import write_simulation
    from mvm.sim.simulate import simulate

    refuse_other_mode(click.get_current_context(), rig, videos)
    if rig:
        return simulate_rig_cmd(scene_dir, preset, people, frames, seed, cameras, offsets, intrinsics_only,
                                video_type if videos else None)

    with refused(ValueError):
        sim = read_sim(config_path, preset, people=people, frames=frames, arc_deg=arc_deg, seed=seed,
                       trajectory=trajectory)
        scene, truth = simulate(sim)
        truth_path = write_simulation(scene_dir, scene, truth, sim)
        if render:
            from mvm.sim.mannequin_video import render_frames

            with stage_progress() as update:
                render_frames(SceneLayout(scene_dir).frames, scene.cameras, truth.poses3d, sim.seed,
                              progress=lambda done, total: update("rendering", done, total))
    labels = ", ".join(f"{truth.labels.count(k)} {k}" for k in dict.fromkeys(truth.labels)) or "–"
    measure_table(f"mvm simulate ({preset})", [
        ("people", f"{len(truth.poses3d)} ({labels})"), ("frames", str(len(scene.cameras))),
        ("2D poses", str(len(scene.poses))), ("false positives", str(int((truth.person < 0).sum()))),
        ("merged poses", str(int((truth.merged_with >= 0).sum()))),
        ("scene", str(scene_dir)), ("ground truth", str(truth_path))]
        + ([("rendered frames", f"{scene_dir}/frames")] if render else []))


#: The options of ``mvm simulate`` that only one mode reads: the option, its parameter, and what
#: to use instead in the other mode.
SCENE_ONLY = (("--arc", "arc_deg", "a rig's cameras stand on a ring"),
              ("--trajectory", "trajectory", "a rig's cameras stand on a ring"),
              ("--render", "render", "--videos renders each camera's video"),
              ("--config", "config_path", "a rig's simulation reads no settings file: --people, --frames, --seed"))
RIG_ONLY = (("--cameras", "cameras", "a scene is one moving camera: --frames, --arc"),
            ("--offsets", "offsets", "a scene is one moving camera"),
            ("--intrinsics-only", "intrinsics_only", "a scene's cameras are in its scene.json"),
            ("--videos", "videos", "a scene's frames: --render"))


def refuse_other_mode(ctx: click.Context, rig: bool, videos: bool) -> None:
    """Refuse, in one line, an option given on the command line that the chosen mode of ``mvm
    simulate`` would ignore (:data:`SCENE_ONLY` with ``--rig``, :data:`RIG_ONLY` without it;
    ``--video-type`` without ``--videos``)."""
    from click.core import ParameterSource

    from mvm.errors import InputError

    def given(name: str) -> bool:
        return ctx.get_parameter_source(name) not in (ParameterSource.DEFAULT, None)

    for option, name, instead in SCENE_ONLY if rig else RIG_ONLY:
        if given(name):
            raise InputError(None, option, f"{'not read with' if rig else 'read only with'} --rig ({instead})")
    if given("video_type") and not videos:
        raise InputError(None, "--video-type", "read only with --rig --videos (the type of the rendered videos)")


def parse_offsets(text: str | None, cameras: int) -> tuple[int, ...]:
    """``"0,3,-2"`` -> ``(0, 3, -2)``, one whole number per camera (None: none)."""
    from mvm.errors import InputError

    if not text:
        return ()
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise InputError("--offsets", text, "expected whole numbers separated by commas, e.g. 0,3,-2") from None
    if len(values) != cameras:
        raise InputError("--offsets", text, f"expected {cameras} numbers (one per camera), got {len(values)}")
    return values


def simulate_rig_cmd(rig_dir, preset, people, frames, seed, cameras, offsets, intrinsics_only, videos=None):
    """``mvm simulate --rig``: a simulated rig folder and its truth (:mod:`mvm.io.rig_simulation`),
    with the preset's detector errors (no merged poses: a rig's detector sees each camera alone),
    or, with ``videos`` (``mp4`` or ``mkv``), each camera's rendered video instead of its poses
    (:mod:`mvm.sim.rig_render`)."""
    import dataclasses
    import functools

    from mvm.io.rig_simulation import write_rig_simulation
    from mvm.sim.rig_render import render_rig_videos
    from mvm.sim.rig_scene import RigSimConfig, simulate_rig
    from mvm.sim.simulate import SimConfig

    with refused(ValueError):
        given = {k: v for k, v in (("people", people), ("frames", frames), ("seed", seed)) if v is not None}
        config = RigSimConfig(cameras=cameras, offsets=parse_offsets(offsets, cameras), **given,
                              errors=dataclasses.replace(SimConfig.preset(preset).detector, merge_prob=0.0))
        sim = simulate_rig(config)
        with stage_progress() as update:
            render = None if not videos else functools.partial(
                render_rig_videos, sim=sim, suffix=f".{videos}", seed=config.seed,
                progress=lambda done, total: update("rendering", done, total))
            paths = write_rig_simulation(rig_dir, sim, intrinsics_only, render)
    names = sim.calibration.cameras.names
    measure_table(f"mvm simulate --rig ({preset})", [
        ("cameras", f"{len(names)} ({', '.join(names)})"), ("people", str(config.people)),
        ("frames per camera", str(config.frames))]
        + ([("videos", f"{paths['videos']} ({videos}, {config.frame_rate:g} Hz, {config.image_width}×"
                       f"{config.image_height}; detect them with mvm rig detect)")] if videos else
           [("2D poses", str(len(sim.keypoints))), ("false positives", str(int((sim.person < 0).sum())))]) + [
        ("offsets to add (sync)", ", ".join(f"{n} {o:+d}" for n, o in zip(names, sim.sync_offsets))),
        ("calibration", f"{paths['calibration']}" + (" (intrinsics only)" if intrinsics_only else "")),
        ("ground truth", f"{paths['truth']}, {paths['true_calibration']}")])


@command("demo")
@scene_options
@click.option("-o", "--out", "out_dir", type=OutputPath(product="a folder (the scene and its ground truth)"),
              default="mvm-demo",
              show_default=True, help="Where to write the simulated scene and its ground truth.")
@click.option("--render", is_flag=True,
              help="Also render the frames into OUT/scene/frames (for mvm report, overlay, export and training).")
@config_options
def demo_cmd(people, frames, arc_deg, seed, out_dir, render, config_path, sets, refine):
    """Simulate a mannequin scene, reconstruct it and print accuracy against ground truth."""
    from mvm.eval.demo import run_demo

    config = read_config(config_path, sets, refine=refine)
    sim = read_sim(config_path, people=people, frames=frames, arc_deg=arc_deg, seed=seed)
    t = time.perf_counter()
    with refused(ValueError), stage_progress() as update:
        report = run_demo(Path(out_dir), sim, config, render=render, progress=update)
    measure_table(f"mvm demo: {sim.people} people, {sim.frames} frames, {sim.arc_deg:g}° tour (seed {sim.seed})", [
        ("persons found / true", f"{report['persons_found']} / {report['persons_true']}"),
        ("2D poses (false positives)", f"{report['poses']} ({report['false_poses']})"),
        ("matching precision (pairwise)", fmt(report["precision"], 4)),
        ("matching recall (pairwise)", fmt(report["recall"], 4)),
        ("MPJPE (mm)", fmt(report["mpjpe_mm"], 1)),
        ("PA-MPJPE (mm)", fmt(report["pa_mpjpe_mm"], 1)),
        ("E_R (px)", fmt(report["E_R_px"])),
        ("outliers per 3D pose", fmt(report["outliers"], 1)),
        ("|G_k| (2D keypoints per joint)", fmt(report["G_k"], 1)),
        ("time: matching / triangulation / refinement (s)",
         " / ".join(fmt(report["timings"][k], 3) for k in ("matching_s", "triangulation_s", "refinement_s"))),
        ("time: whole demo (s)", fmt(time.perf_counter() - t)),
    ])
    say(f"scene: {report['scene']}  result: {report['poses3d']}  ground truth: {report['ground_truth']}")


@command("bench")
@click.option("--quick", is_flag=True, help="Two tiny clips and short sweeps (seconds, for CI).")
@click.option("-o", "--out", "out_dir", type=OutputPath(product="a folder of tables and plots"),
              default="benchmarks/results",
              show_default=True, help="Folder for paper_tables.md, clips.csv, sweeps.csv, matching_time.png.")
@click.option("--refine/--no-refine", default=False, show_default=True, help="Run the pose-prior refinement.")
@click.option("--trajectories", type=click.Path(file_okay=False, exists=True), default=None,
              help="Folder of real camera paths (*.txt) used by some clips.")
def bench_cmd(quick, out_dir, refine, trajectories):
    """Reproduce the paper's Tables 1-2 on simulated clips with ground truth, plus sweeps."""
    from mvm.core.config import Config
    from mvm.eval.bench import run_bench
    from mvm.eval.bench_files import BENCH_FILES, write_bench_report
    from mvm.io.outputs import check_names

    check_names(out_dir, BENCH_FILES)                 # a user's file there: refused before the work
    paths = sorted(str(p) for p in Path(trajectories).glob("*.txt")) if trajectories else []
    t = time.perf_counter()
    result = run_bench(quick=quick, config=Config(refine=refine), trajectories=paths)
    seconds = time.perf_counter() - t
    command_line = "mvm bench" + (" --quick" if quick else "") + (" --refine" if refine else "")
    path = write_bench_report(result, out_dir, command_line, seconds)
    print_table(f"mvm bench: Table 1 ({len({r['clip'] for r in result.rows})} clips, {seconds:.0f} s)",
                ("method", "E_R px", "|G_k|", "F1", "MPJPE mm", "matching s"),
                [(row["method"], f"{row['E_R_px']:.1f}", f"{row['G_k']:.1f}", f"{row['f1']:.3f}",
                  f"{row['mpjpe_mm']:.1f}", f"{row['matching_s']:.3f}")
                 for row in result.table1 + result.table1_short[:1]])
    say(f"tables: {path}")
