"""``mvm report`` and ``mvm overlay`` as stages (:mod:`mvm.stages.view_report`, :mod:`mvm.stages.view_overlay`):
made once with a record, kept on a second run (not rewritten), made again with the reason when
what they are drawn from or a setting changes, forced with ``--force``; a rig's page and its
record go with the output set."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

pytest.importorskip("cv2")

from test_report import make_scene  # noqa: E402

from mvm.cli.report import overlay_cmd, report_cmd  # noqa: E402
from mvm.core.config import Config  # noqa: E402
from mvm.errors import InputError  # noqa: E402
from mvm.io.outputs import OUTPUT_MARKER  # noqa: E402
from mvm.io.provenance import read_record, record_path  # noqa: E402
from mvm.io.rig_simulation import write_rig_simulation  # noqa: E402
from mvm.rig.options import RigOptions  # noqa: E402
from mvm.rig.reconstruct_rig import reconstruct_rig  # noqa: E402
from mvm.sim.rig_scene import RigSimConfig, simulate_rig  # noqa: E402
from mvm.stages import VIEW_STAGES, run_stage  # noqa: E402
from mvm.stages.view import ViewJob  # noqa: E402
from mvm.stages.view_overlay import STAGE as OVERLAY  # noqa: E402
from mvm.stages.view_report import STAGE as REPORT  # noqa: E402


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("views") / "scene"
    make_scene(path, people=2, frames=12)
    return path


def _mtime(path):
    return path.stat().st_mtime_ns


def _reformat(poses3d):
    """The same 3D poses in other bytes (the reconstruction's record does not hash its output)."""
    poses3d.write_text(json.dumps(json.loads(poses3d.read_text()), indent=3))


def test_the_view_stages():
    assert [s.name for s in VIEW_STAGES] == ["report", "overlay"]


def test_a_scene_report_made_kept_redone_forced(scene, tmp_path):
    job = ViewJob(scene, out=tmp_path / "page.html")
    assert REPORT.applies(job) is None and REPORT.applies(ViewJob(tmp_path)) is not None
    assert run_stage(REPORT, job).why == "no output yet"
    page = tmp_path / "page.html"
    assert read_record(page)["stage"] == "the report" and read_record(page)["settings"] == {"frames": 8}
    made = _mtime(page)
    kept = run_stage(REPORT, job)
    assert kept.why is None and kept.result == page and _mtime(page) == made

    assert run_stage(REPORT, ViewJob(scene, out=page, frames=4)).why == \
        "setting frames changed since the report (8 -> 4)"
    _reformat(scene / "mvm" / "poses3d.json")
    assert REPORT.why(ViewJob(scene, out=page, frames=4)) == "mvm/poses3d.json changed since the report"
    assert run_stage(REPORT, ViewJob(scene, out=page, frames=4)).why == "mvm/poses3d.json changed since the report"
    assert run_stage(REPORT, ViewJob(scene, out=page, frames=4), force=True).why == "forced"

    before = _mtime(page)
    result = CliRunner().invoke(report_cmd, [str(scene), "-o", str(page), "--frames", "4"])
    assert result.exit_code == 0 and f"kept {page}" in result.output and _mtime(page) == before, result.output
    result = CliRunner().invoke(report_cmd, [str(scene), "-o", str(page), "--frames", "4", "--force"])
    assert result.exit_code == 0 and f"kept {page}" not in result.output and _mtime(page) > before, result.output


def test_a_scene_overlay_made_kept_redone_forced(scene, tmp_path):
    out = tmp_path / "ov"
    job = ViewJob(scene, out=out, step=6, max_width=64)
    done = run_stage(OVERLAY, job)
    assert done.why == "no output yet" and done.result.frames == 2
    assert [p.name for p in OVERLAY.files(job)] == ["frame_00000.jpg", "frame_00006.jpg"]
    assert read_record(out / "overlay")["stage"] == "the overlay"             # a folder keeps its record inside
    assert record_path(out / "overlay") == out / "overlay.inputs.json" and not (tmp_path / "ov.inputs.json").exists()
    made = {p.name: _mtime(p) for p in OVERLAY.files(job)}
    assert run_stage(OVERLAY, job).why is None and {p.name: _mtime(p) for p in OVERLAY.files(job)} == made

    assert run_stage(OVERLAY, ViewJob(scene, out=out, step=4, max_width=64)).why == \
        "setting step changed since the overlay (6 -> 4)"
    assert len(OVERLAY.files(job)) == 3
    result = CliRunner().invoke(overlay_cmd, [str(scene), "-o", str(out), "--every", "4", "--max-width", "64"])
    assert result.exit_code == 0 and f"kept {out}" in result.output, result.output
    result = CliRunner().invoke(overlay_cmd, [str(scene), "-o", str(out), "--every", "4", "--max-width", "64",
                                              "--force"])
    assert result.exit_code == 0 and "3 frames drawn" in result.output, result.output


def test_a_page_named_over_another_outputs_record_is_refused(scene):
    """``-o SCENE/poses2d.html``: its record would be ``poses2d.inputs.json``, the detection's."""
    with pytest.raises(InputError, match="its record would be poses2d.inputs.json"):
        run_stage(REPORT, ViewJob(scene, out=scene / "poses2d.html"))
    assert not (scene / "poses2d.html").exists()


@pytest.mark.parametrize("mine", [b'{"my": "notes"}', b"not json at all", b""])
def test_a_page_or_video_beside_a_users_file_of_its_records_name_is_refused(scene, tmp_path, mine):
    """``-o x/page.html`` (or ``x/v.mp4``) where ``x/page.inputs.json`` is a user's own file: refused
    in one line naming the output, before anything is written, the user's file as it was."""
    for stage, name in ((REPORT, "page.html"), (OVERLAY, "v.mp4")):
        folder = tmp_path / name.split(".")[0]
        folder.mkdir()
        out = folder / name
        (folder / f"{out.stem}.inputs.json").write_bytes(mine)
        with pytest.raises(InputError, match="no record of mvm's") as refused:
            run_stage(stage, ViewJob(scene, out=out, step=6, max_width=64))
        assert refused.value.path == str(out)
        assert (folder / f"{out.stem}.inputs.json").read_bytes() == mine and not out.exists()


def test_a_rig_report_goes_with_its_output_set(tmp_path):
    root = tmp_path / "rig"
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=30, seed=6))
    write_rig_simulation(root, sim)
    reconstruct_rig(root, Config(refine=False), RigOptions(workers=1))
    job = ViewJob(root)
    assert run_stage(REPORT, job).why == "no output yet"
    page = root / "mvm" / "report.html"
    marker = json.loads((root / "mvm" / OUTPUT_MARKER).read_text())
    assert {"report.html", "report.inputs.json"} <= set(marker)
    made = _mtime(page)
    assert run_stage(REPORT, job).why is None and _mtime(page) == made

    pose = root / "pose" / "cam_02.json"
    pose.write_text(json.dumps(json.loads(pose.read_text()), indent=2))
    assert REPORT.why(job) == "pose changed since the report"
    with pytest.raises(InputError, match="out of date"):
        run_stage(REPORT, job)                          # drawn from a stale output set: refused, as before
    reconstruct_rig(root, Config(refine=False), RigOptions(workers=1))     # the set replaced, the page with it
    assert not page.exists() and not record_path(page).exists()
    assert run_stage(REPORT, job).why == "no output yet"
