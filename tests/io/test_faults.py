"""Fault tests: ``mvm reconstruct`` killed with SIGKILL at random moments and at chosen points
of writing (between the temporary file and the rename, half-way through the write, just after
the rename), and several runs on one scene at once.

After every kill the output is either absent (first run) or complete and valid — the previous
complete output when there was one: an output is never lost nor partial. A clean rerun then
writes the complete output and removes the killed run's temporary file.

Output locations (:data:`LOCATIONS`): the commands that write folders (``export``, ``overlay``,
``rig reconstruct``) pointed at their inputs, at a folder holding them, inside one, through a
link, at a user's folder, beside a user's ``.NAME.*`` folders. A refused location ends in one
line, exit 2, and changes nothing on disk; an allowed one changes nothing but the output.

``benchmarks/fault_injection.py`` runs the same faults many more times and prints the counts.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL") or sys.platform == "win32",
                                reason="SIGKILL and flock are POSIX")

#: Python run before the command line in the child process; ``FAULT`` selects where it kills
#: itself while writing ``poses3d.json``.
PRELUDE = r'''
import os, signal, sys
fault = os.environ.get("MVM_TEST_FAULT", "")
target = "poses3d.json"
if fault.startswith("record_"):                  # the same points of writing the output's record
    fault, target = fault[len("record_"):], "poses3d.inputs.json"
def die():
    os.kill(os.getpid(), signal.SIGKILL)
if fault in ("before_rename", "after_rename"):
    real_replace = os.replace
    def replace(src, dst, *a, **k):
        if str(dst).endswith(target):
            if fault == "before_rename":
                die()
            real_replace(src, dst, *a, **k)
            die()
        return real_replace(src, dst, *a, **k)
    os.replace = replace
if fault == "mid_write":
    real_fdopen = os.fdopen
    class HalfWriter:
        def __init__(self, f):
            self.f = f
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            return self.f.__exit__(*exc)
        def write(self, data):
            self.f.write(data[: len(data) // 2])
            self.f.flush()
            os.fsync(self.f.fileno())
            die()
        def __getattr__(self, name):
            return getattr(self.f, name)
    def fdopen(fd, mode="r", *a, **k):
        name = os.readlink(f"/proc/self/fd/{fd}") if os.path.exists(f"/proc/self/fd/{fd}") else target
        f = real_fdopen(fd, mode, *a, **k)
        return HalfWriter(f) if "w" in mode and f".{target}." in name else f
    os.fdopen = fdopen
from mvm.cli.main import run
sys.argv = ["mvm"] + sys.argv[1:]
run()
'''

FAULTS = ("before_rename", "mid_write", "after_rename",
          "record_before_rename", "record_mid_write", "record_after_rename")


def write_test_scene(path: Path, people: int = 3, frames: int = 30, seed: int = 0) -> Path:
    try:
        from helpers import standing_poses
    except ImportError:
        from tests.conftest import standing_poses
    from mvm.io.scene_dir import write_scene
    from mvm.sim.simulate import SimConfig, simulate

    scene, _ = simulate(SimConfig(people=people, frames=frames, seed=seed), bank_poses=standing_poses())
    write_scene(path, scene.cameras, scene.poses)
    return path


def start(scene: Path, fault: str = "", *extra: str) -> subprocess.Popen:
    env = dict(os.environ, MVM_TEST_FAULT=fault)
    return subprocess.Popen([sys.executable, "-c", PRELUDE, "reconstruct", str(scene), *extra], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def output_of(scene: Path) -> Path:
    return scene / "mvm" / "poses3d.json"


def persons_of(path: Path):
    """The persons of a complete, valid ``poses3d.json`` (raises on a partial or invalid one)."""
    document = json.loads(path.read_text())
    assert document["format"] == "mvm.poses3d/1"
    assert set(document) >= {"persons", "metrics", "config", "warnings"}
    for person in document["persons"]:
        assert len(person["keypoints3d"]) == 17
    return document["persons"]


def state(scene: Path, reference) -> str:
    """``absent``, ``complete`` (valid and equal to the reference persons) or ``partial``."""
    path = output_of(scene)
    if not path.exists():
        return "absent"
    try:
        return "complete" if persons_of(path) == reference else "partial"
    except (ValueError, KeyError, AssertionError, TypeError):
        return "partial"


def stale_temporaries(scene: Path) -> list[Path]:
    """The temporaries of ``poses3d.json`` and of its record (``poses3d.inputs.json``)."""
    return sorted((scene / "mvm").glob(".poses3d.*.tmp")) if (scene / "mvm").exists() else []


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """A scene and its complete output, from an undisturbed run."""
    scene = write_test_scene(tmp_path_factory.mktemp("ref") / "scene")
    process = start(scene)
    assert process.wait(120) == 0, process.stderr.read().decode()
    return scene, persons_of(output_of(scene))


def copy_scene(scene: Path, to: Path, with_output: bool) -> Path:
    import shutil

    shutil.copytree(scene, to, ignore=None if with_output else shutil.ignore_patterns("mvm"))
    return to


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("with_output", [False, True], ids=["fresh", "rerun"])
def test_killed_while_writing_then_rerun(reference, tmp_path, fault, with_output):
    scene = copy_scene(reference[0], tmp_path / "scene", with_output)
    process = start(scene, fault)
    assert process.wait(120) == -signal.SIGKILL
    after_kill = state(scene, reference[1])
    if fault.endswith("after_rename") or fault.startswith("record_"):
        assert after_kill == "complete"
    elif with_output:
        assert after_kill == "complete"                  # the previous output survives
    else:
        assert after_kill == "absent"
    if not fault.endswith("after_rename"):
        assert stale_temporaries(scene)                  # the fault did hit the write
    rerun = start(scene)
    assert rerun.wait(120) == 0, rerun.stderr.read().decode()
    assert state(scene, reference[1]) == "complete"
    assert stale_temporaries(scene) == []


def test_killed_at_random_moments(reference, tmp_path):
    rng = np.random.default_rng(0)
    outcomes = []
    for i in range(6):
        scene = copy_scene(reference[0], tmp_path / f"s{i}", with_output=bool(i % 2))
        process = start(scene)
        time.sleep(rng.uniform(0.2, 1.2))
        process.send_signal(signal.SIGKILL)
        process.wait(120)
        outcome = state(scene, reference[1])
        assert outcome != "partial"
        if i % 2:
            assert outcome == "complete"
        outcomes.append(outcome)
        rerun = start(scene)
        assert rerun.wait(120) == 0
        assert state(scene, reference[1]) == "complete" and stale_temporaries(scene) == []


def test_concurrent_runs_on_one_scene(reference, tmp_path):
    scene = copy_scene(reference[0], tmp_path / "scene", with_output=False)
    processes = [start(scene) for _ in range(3)]
    codes = [p.wait(180) for p in processes]
    assert codes == [0, 0, 0], [p.stderr.read().decode() for p in processes]
    assert state(scene, reference[1]) == "complete"
    assert stale_temporaries(scene) == []
    assert sorted(p.name for p in (scene / "mvm").iterdir()) == ["poses3d.inputs.json", "poses3d.json", "timings.json"]


def test_a_run_that_cannot_get_the_lock_refuses_cleanly(reference, tmp_path):
    from mvm.io.outputs import output_lock

    scene = copy_scene(reference[0], tmp_path / "scene", with_output=True)
    before = output_of(scene).read_bytes()
    with output_lock(scene / "mvm" / "poses3d.json"):
        process = start(scene, "", "--set", "lock_timeout_s=0.2")
        code = process.wait(120)
    stderr = process.stderr.read().decode()
    assert code == 2
    lines = [line for line in stderr.splitlines() if line.startswith("mvm: error:")]
    assert len(lines) == 1 and "another mvm run" in lines[0] and "Traceback" not in stderr
    assert output_of(scene).read_bytes() == before


# ---------------------------------------------------------------------------- output locations

#: Where an output folder is pointed, and whether mvm may write there.
LOCATIONS = {"the input folder": False, "the folder holding the inputs": False, "inside an input folder": False,
             "a link to an input folder": False, "an input folder by a path with ..": False,
             "a user's folder": False, "mvm's output holding a user's file": False,
             "a new folder": True, "an empty folder": True, "mvm's own output, again": True,
             "beside a user's .NAME.* folders": True}
#: The commands that write a folder, as ``(name, args before the output, output option)``.
FOLDER_COMMANDS = ("export", "overlay", "rig")


def write_location_inputs(root: Path) -> dict:
    """A reconstructed scene with frames (``root/scene``) and a rig (``root/rig``), each with a
    user's notes beside its inputs: what the location cases point outputs at."""
    import shutil

    import cv2

    from mvm.io.scene_dir import read_scene

    scene = write_test_scene(root / "scene", people=2, frames=8)
    assert start(scene).wait(120) == 0
    (scene / "frames").mkdir()
    for name in read_scene(scene).cameras.names:
        cv2.imwrite(str(scene / "frames" / name), np.full((36, 64, 3), 120, np.uint8))
    (scene / "notes.txt").write_text("a user's notes")
    rig = root / "rig"
    rig.mkdir()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "rig"))
    try:
        from test_rig_dir import _write_rig
    finally:
        sys.path.pop(0)
    _write_rig(rig, T=4)
    (rig / "notes.txt").write_text("a user's notes")
    shutil.rmtree(rig / "mvm", ignore_errors=True)
    return {"scene": scene, "rig": rig}


def command_line(command: str, inputs: dict, output: Path) -> list[str]:
    if command == "export":
        return ["export", str(inputs["scene"]), "--out", str(output), "--link", "copy"]
    if command == "overlay":
        return ["overlay", str(inputs["scene"]), "-o", str(output), "--every", "3", "--max-width", "32"]
    return ["rig", "reconstruct", str(inputs["rig"]), "-o", str(output), "--no-refine", "--workers", "1"]


def run_in_process(args: list[str]) -> tuple[int, list[str]]:
    """Exit status and every output line of ``mvm ARGS`` (never a traceback)."""
    from click.testing import CliRunner

    from mvm.cli.main import main

    result = CliRunner().invoke(main, args)
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    return result.exit_code, result.output.strip().splitlines()


def place_output(kind: str, command: str, inputs: dict, work: Path, name: str = "out") -> Path:
    """The output path of location ``kind`` for ``command``, set up under ``work``."""
    source = inputs["rig"] if command == "rig" else inputs["scene"]
    folder = source / "pose" if command == "rig" else source / "frames"
    output = work / name
    if kind == "the input folder":
        return folder
    if kind == "the folder holding the inputs":
        return source
    if kind == "inside an input folder":
        return folder / name
    if kind == "a link to an input folder":
        output.symlink_to(folder, target_is_directory=True)
    elif kind == "an input folder by a path with ..":
        return folder / ".." / folder.name
    elif kind == "a user's folder":
        (output / "data").mkdir(parents=True)
        (output / "thesis.tex").write_text("chapter 1")
        (output / "data" / "x.csv").write_text("1,2")
    elif kind == "an empty folder":
        output.mkdir()
    elif kind in ("mvm's own output, again", "mvm's output holding a user's file"):
        assert run_in_process(command_line(command, inputs, output))[0] == 0
        if kind == "mvm's output holding a user's file":
            (output / "notes.txt").write_text("mine")
    elif kind == "beside a user's .NAME.* folders":
        for sibling in (f".{name}.backup", f".{name}.old", f".{name}.mvm-tmp-mine"):
            (work / sibling).mkdir()
            (work / sibling / "notes.txt").write_text(sibling)
    elif kind == "a new folder":
        output = work / name / "deeper"
    return output


def tree(root: Path) -> dict:
    """Every file and link under ``root`` with its content (a link: its target)."""
    found = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for n in dirnames + filenames:
            p = Path(dirpath) / n
            if p.is_symlink():
                found[p.relative_to(root).as_posix()] = "-> " + os.readlink(p)
            elif p.is_file():
                found[p.relative_to(root).as_posix()] = p.read_bytes()
    return found


def check_location(kind: str, command: str, inputs: dict, work: Path, name: str = "out") -> str:
    """Run ``command`` into location ``kind``; return what happened ("refused" or "written") after
    asserting the invariants: a refusal is one line, exit 2, nothing changed anywhere; a write
    changes only the output and leaves no temporary folder nor lock file."""
    output = place_output(kind, command, inputs, work, name)
    roots = [inputs["scene"].parent, work]
    before = [tree(r) for r in roots]
    code, lines = run_in_process(command_line(command, inputs, output))
    allowed = LOCATIONS[kind]
    if not allowed:
        errors = [line for line in lines if line.startswith("mvm: error:")]
        assert code == 2 and len(errors) == 1 and errors[0].startswith(f"mvm: error: {output}: "), (kind, lines)
        assert [tree(r) for r in roots] == before, kind
        return "refused"
    assert code == 0, (kind, command, lines)
    prefix = output.relative_to(work).as_posix() + "/"
    after = [{k: v for k, v in tree(r).items() if not k.startswith(prefix)} for r in roots]
    unchanged = [{k: v for k, v in t.items() if not k.startswith(prefix)} for t in before]
    assert after == unchanged, kind
    assert not [p for p in output.parent.iterdir() if p.name.startswith(f".{output.name}.lock")
                or p.name.startswith(f".{output.name}.mvm-tmp-") and (p / ".mvm-temporary").exists()]
    return "written"


@pytest.fixture(scope="module")
def location_inputs(tmp_path_factory):
    return write_location_inputs(tmp_path_factory.mktemp("locations"))


@pytest.mark.parametrize("command", FOLDER_COMMANDS)
@pytest.mark.parametrize("kind", list(LOCATIONS))
def test_outputs_never_land_among_inputs_nor_on_a_users_folder(location_inputs, tmp_path, kind, command):
    outcome = check_location(kind, command, location_inputs, tmp_path)
    assert outcome == ("written" if LOCATIONS[kind] else "refused")
