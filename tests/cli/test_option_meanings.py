"""One meaning per option across commands: ``--config``, ``--set`` and ``--refine`` wherever a
reconstruction runs; ``-o`` the output path of the command's main product; an output name with
an image or video suffix writes that format or is refused."""
import pytest
from click.testing import CliRunner

from mvm.cli.main import COMMANDS, main

#: The commands that run a reconstruction.
RECONSTRUCTING = [("run",), ("batch",), ("reconstruct",), ("demo",), ("rig", "reconstruct")]
#: The commands whose main product is a path: ``-o`` gives it.
WRITING = [("run",), ("frames",), ("demo",), ("bench",), ("export",), ("predict",), ("report",), ("overlay",),
           ("rig", "reconstruct")]


def _command(names):
    command = main.get_command(None, names[0])
    return command if len(names) == 1 else command.get_command(None, names[1])


@pytest.mark.parametrize("names", RECONSTRUCTING, ids=" ".join)
def test_every_reconstruction_takes_config_set_and_refine(names):
    options = {opt for p in _command(names).params for opt in p.opts + p.secondary_opts}
    assert {"--config", "--set", "--refine", "--no-refine"} <= options


@pytest.mark.parametrize("names", WRITING, ids=" ".join)
def test_o_is_the_output_path(names):
    from mvm.cli.common import OutputPath

    option = next(p for p in _command(names).params if "-o" in p.opts)
    assert isinstance(option.type, OutputPath)


def _every_command():
    """``(names, command)`` of every command and subcommand of ``mvm``."""
    import click

    found = []
    for name in COMMANDS:
        command = _command((name,))
        if isinstance(command, click.Group):
            found += [((name, sub), command.get_command(None, sub)) for sub in command.list_commands(None)]
        else:
            found.append(((name,), command))
    return found


def test_o_is_spelled_out_one_way():
    """``-o`` is ``--out`` in every command; no option is ``--output`` any more (it was a second
    spelling of ``-o`` in four commands, and a hidden spelling of ``--output-name``)."""
    spellings = {}
    for names, command in _every_command():
        for param in command.params:
            assert "--output" not in param.opts, names
            if "-o" in param.opts:
                spellings[names] = tuple(sorted(param.opts))
    assert ("rig", "calibrate") in spellings and ("frames",) in spellings and len(spellings) == 10, spellings
    assert set(spellings.values()) == {("--out", "-o")}, spellings


def _scene(tmp_path):
    scene = tmp_path / "scene"
    result = CliRunner().invoke(main, ["simulate", str(scene), "--people", "2", "--frames", "20"])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(main, ["reconstruct", str(scene), "--workers", "1", "--no-refine"])
    assert result.exit_code == 0, result.output
    return scene


@pytest.mark.parametrize("args, problem", [
    (["overlay", "{scene}", "-o", "{d}/out.gif"], "-o: {d}/out.gif names an image (.gif), but mvm overlay writes a "
                                                  ".mp4 video or a folder of images"),
    (["overlay", "{scene}", "-o", "{d}/out.avi"], "-o: {d}/out.avi names a video (.avi), but mvm overlay writes a "
                                                  ".mp4 video or a folder of images"),
    (["report", "{scene}", "-o", "{d}/page.png"], "-o: {d}/page.png names an image (.png), but mvm report writes an "
                                                  ".html page"),
    (["report", "{scene}", "-o", "{d}/page"], "-o: {d}/page names no file type, but mvm report writes an .html page"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene.mp4"], "-o: {d}/scene.mp4 names a video (.mp4), but mvm frames "
                                                        "writes a scene directory"),
    (["demo", "-o", "{d}/demo.jpg"], "-o: {d}/demo.jpg names an image (.jpg), but mvm demo writes a folder (the "
                                     "scene and its ground truth)"),
])
def test_an_image_or_video_name_is_written_in_that_format_or_refused(tmp_path, args, problem):
    scene = tmp_path / "scene"
    scene.mkdir()
    args = [a.format(scene=scene, d=tmp_path) for a in args]
    before = sorted(tmp_path.rglob("*"))
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == f"mvm: error: {problem.format(d=tmp_path)}"
    assert sorted(tmp_path.rglob("*")) == before


def test_report_and_overlay_write_where_o_says(tmp_path):
    scene = _scene(tmp_path)
    result = CliRunner().invoke(main, ["report", str(scene), "--frames", "0", "-o", str(tmp_path / "page.html")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "page.html").read_text().startswith("<!") and not (scene / "mvm" / "report.html").exists()
    result = CliRunner().invoke(main, ["overlay", str(scene), "--every", "10", "-o", str(tmp_path / "o.mp4")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "o.mp4").is_file() and (tmp_path / "o.mp4").stat().st_size > 1000


def test_output_name_names_the_folder_inside_the_scene(tmp_path):
    scene = _scene(tmp_path)
    runner = CliRunner()
    result = runner.invoke(main, ["reconstruct", str(scene), "--workers", "1", "--no-refine", "--output-name", "b"])
    assert result.exit_code == 0 and result.stderr == "", result.output
    assert (scene / "b" / "poses3d.json").is_file()
    result = runner.invoke(main, ["report", str(scene), "--frames", "0", "--output-name", "b"])
    assert result.exit_code == 0 and (scene / "b" / "report.html").is_file(), result.output
    for args in (["reconstruct", str(scene), "-o", "c"], ["report", str(scene), "--output", "c"]):
        result = runner.invoke(main, args)
        assert result.exit_code == 2 and "No such option" in result.stderr, result.output
    assert not (scene / "c").exists()


def test_run_and_batch_read_set_and_refine(tmp_path, monkeypatch):
    """``mvm run --set`` and ``mvm batch --refine`` reach the reconstruction settings."""
    import mvm.stages.run as run
    from mvm.cli.batch import read_batch_options

    assert read_batch_options(None, ("tau=0.3",), refine=False).config.refine is False
    assert read_batch_options(None, ("tau=0.3",), refine=False).config.tau == 0.3
    seen = {}

    def fake_run_video(video, scene, **kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(run, "run_video", fake_run_video)
    (tmp_path / "clip.mp4").write_bytes(b"")
    (tmp_path / "x.json").write_text("[]")
    result = CliRunner().invoke(main, ["run", str(tmp_path / "clip.mp4"), "-o", str(tmp_path / "s"), "--import",
                                       str(tmp_path / "x.json"), "--set", "tau=0.3", "--no-refine"])
    assert seen["config"].tau == 0.3 and seen["config"].refine is False, result.output
    result = CliRunner().invoke(main, ["run", str(tmp_path / "clip.mp4"), "-o", str(tmp_path / "s"), "--import",
                                       str(tmp_path / "x.json"), "--set", "no_such=1"])
    assert result.exit_code == 2 and "--set: no_such: not a setting of mvm run" in result.stderr
