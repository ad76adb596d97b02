"""``mvm config``: the reference settings file is generated from the settings dataclasses, passes
its own check, and each table read back gives the defaults; ``--check`` refuses a bad file in
one line naming the file, the key and the problem."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.core.config import Config
from mvm.rig.options import RigOptions
from mvm.settings.reference import check_settings_file, field_docs, reference_toml, split_unit, table_class
from mvm.settings.tables import TABLES, load_config, load_settings


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    result = CliRunner().invoke(main, ["config"])
    assert result.exit_code == 0, result.output
    path = tmp_path_factory.mktemp("settings") / "mvm.toml"
    path.write_text(result.stdout)
    return path


def test_every_table_and_key_is_printed_with_its_default(reference):
    assert all(dataclasses.is_dataclass(table_class(name)) for name in TABLES)
    text = reference.read_text()
    for name in TABLES:
        assert f"\n[{name}]\n" in text
    assert "\nkeypoint_threshold = 0.2\n" in text and '\nassociation = "auto"\n' in text
    assert "\n# complete =    (unset)\n" in text
    assert "[detect.rtm]" in text and "[simulate.detector]" in text
    # the comment of a setting: its sentence, then its unit and allowed values
    assert "\n# unit: person sizes; allowed: float (> 0)\nransac_threshold = 0.12\n" in text
    assert '# allowed: one of "auto", "paper", "3d"\nassociation = "auto"' in text


def test_the_printed_file_passes_its_check_and_reads_back_as_the_defaults(reference):
    result = CliRunner().invoke(main, ["config", "--check", str(reference)])
    assert result.exit_code == 0, result.output
    assert result.stdout == f"{reference}: OK ({', '.join(f'[{t}]' for t in TABLES)})\n"
    checked = check_settings_file(reference)
    assert list(checked) == list(TABLES)
    for name, settings in checked.items():
        assert settings == table_class(name)(), name
    # as the commands read it with --config
    assert load_config(reference) == Config()
    assert load_settings(RigOptions, "rig", reference) == RigOptions()
    from mvm.batch import BatchOptions
    from mvm.cli.batch import read_batch_options
    from mvm.cli.common import read_config
    from mvm.cli.rig import read_rig_options

    assert read_config(str(reference), ()) == Config()
    assert read_rig_options(str(reference), ()) == RigOptions()
    assert read_batch_options(str(reference), ()) == BatchOptions()


def test_a_changed_value_is_read_by_the_command(reference, tmp_path):
    path = tmp_path / "edited.toml"
    path.write_text(reference.read_text().replace("\nmax_gap = 10\n", "\nmax_gap = 3\n")
                    .replace("\ntau = 0.2\n", "\ntau = 0.3\n")
                    .replace('\nassociation = "auto"\n', '\nassociation = "3d"\n'))
    from mvm.cli.rig import read_rig_options

    assert read_rig_options(str(path), ()) == RigOptions(max_gap=3)
    from mvm.cli.batch import read_batch_options

    edited = path.read_text().replace("\njpeg_quality = 95\n", "\njpeg_quality = 80\n")
    path.write_text(edited.replace('\n# detector =    (unset)\n', '\ndetector = "rtmo"\n'))
    batch = read_batch_options(str(path), (), rate=2.0)
    assert (batch.frames.jpeg_quality, batch.frames.rate, batch.detect.detector, batch.config.tau) == \
        (80, 2.0, "rtmo", 0.3)
    assert load_config(path) == Config(tau=0.3, association="3d")


#: (the text of a settings file, the problem after ``FILE: ``).
BAD_FILES = [("[reconstrut]\ntau = 0.3", "reconstrut: unknown table (known: " + ", ".join(TABLES) + ")"),
             ("[rig]\nmax_gapp = 3", "rig.max_gapp: unknown setting (known: "
              + ", ".join(sorted(f.name for f in dataclasses.fields(RigOptions))) + ")"),
             ("[reconstruct]\ntau = \"high\"", "reconstruct.tau: expected float, got 'high'"),
             ("tau = -1", "reconstruct.tau: must be >= 0, got -1.0"),
             ("[rig]\nsavgol_window = 8", "rig.savgol_window: must be odd, got 8"),
             ("[frames]\njpeg_quality = 101", "frames.jpeg_quality: must be <= 100, got 101"),
             ("[detect.rtm]\niou_threshold = 2", "detect.rtm.iou_threshold: must be <= 1, got 2.0"),
             ("[simulate]\nsize_range = [1]", "simulate.size_range: expected 2 numbers, got [1]"),
             ("[simulate.detector]\ndropout = 1.5", "simulate.detector.dropout: must be <= 1, got 1.5"),
             ("[sfm]\ncamera_model = \"SIMPLE\"", "sfm.camera_model: expected one of"),
             ("[batch]\nmin_keypoints = 0", "batch.min_keypoints: must be >= 1, got 0"),
             ("[train]\noptimizer = \"adam\"", "train.optimizer: expected one of 'sgd', 'adamw', got 'adam'"),
             ("[reconstruct\ntau = 1", "not valid TOML")]


@pytest.mark.parametrize("text, problem", BAD_FILES)
def test_check_refuses_a_bad_file_in_one_line(tmp_path, text, problem):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    result = CliRunner().invoke(main, ["config", "--check", str(path)])
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith(f"mvm: error: {path}: {problem}") and result.stderr.count("\n") == 1
    assert result.stdout == ""


def test_every_setting_has_a_comment_ending_in_its_unit():
    for name in TABLES:
        if name == "train":                                            # documented in its docstring
            continue
        classes = [table_class(name)]
        while classes:
            cls = classes.pop()
            docs = field_docs(cls)
            for field in dataclasses.fields(cls):
                assert field.name in docs, f"{cls.__name__}.{field.name} has no #: comment"
                text, unit = split_unit(docs[field.name])
                assert text and unit, f"{cls.__name__}.{field.name}: no [unit] at the end of its comment"
                default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
                if dataclasses.is_dataclass(default):
                    classes.append(type(default))


def test_config_check_without_train_does_not_import_torch(reference, tmp_path):
    path = tmp_path / "small.toml"
    path.write_text("[reconstruct]\ntau = 0.3\n[rig]\nmax_gap = 3\n")
    code = ("import sys; from mvm.settings.reference import check_settings_file; "
            f"check_settings_file({str(path)!r}); print('torch' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "False"
    assert reference_toml(("reconstruct",)).count("\n[") == 1


def test_a_table_name_given_a_value_is_refused(tmp_path):
    path = tmp_path / "flat.toml"
    path.write_text("reconstruct = 3\n")
    result = CliRunner().invoke(main, ["config", "--check", str(path)])
    assert (result.exit_code, result.stderr) == (2, f"mvm: error: {path}: reconstruct: expected a table of settings\n")


@pytest.mark.parametrize("args, text, line", [
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene"], "[frames]\njpeg_quality = 101",
     "jpeg_quality: must be <= 100, got 101"),
    (["sfm", "{d}/scene"], "[sfm]\nmax_features = 10", "max_features: must be >= 64, got 10"),
    (["detect", "{d}/scene", "--import", "{d}/x.json"], "[detect]\nmode = \"huge\"", "mode: expected one of"),
    (["run", "{d}/clip.mp4", "-o", "{d}/scene", "--import", "{d}/x.json"], "[detect.rtm]\nscore_threshold = -1",
     "rtm.score_threshold: must be >= 0, got -1.0"),
    (["batch", "{d}/root"], "[sfm]\ncamera_model = \"PINHOL\"", "camera_model: expected one of"),
    (["simulate", "{d}/sim"], "[simulate]\npeople = 0", "people: must be >= 1, got 0"),
    (["demo", "-o", "{d}/demo"], "[simulate.detector]\ndropout = 2", "detector.dropout: must be <= 1, got 2.0"),
])
def test_the_video_commands_read_their_tables(tmp_path, args, text, line):
    path = tmp_path / "settings.toml"
    path.write_text(text)
    result = CliRunner().invoke(main, [a.format(d=tmp_path) for a in args] + ["--config", str(path)])
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith(f"mvm: error: {path}: {line}") and result.stderr.count("\n") == 1


def test_an_option_given_wins_over_the_file(tmp_path):
    from mvm.cli.video import _frame_options, _sfm_options
    from mvm.video.frames import FrameOptions
    from mvm.video.sfm import SfmOptions

    path = tmp_path / "settings.toml"
    path.write_text("[frames]\nblur_ratio = 0.5\nwidth = 640\n[sfm]\nmax_features = 2048\nrefine_focal = true\n")
    assert _frame_options(str(path), None, None, 320, None) == FrameOptions(blur_ratio=0.5, width=320)
    assert _sfm_options(str(path), None, 800.0, True, None, None) == \
        SfmOptions(max_features=2048, focal_px=800.0, refine_focal=False)
    assert _frame_options(None, None, None, None, None) == FrameOptions()
    from mvm.cli.sim import read_sim
    from mvm.sim.simulate import SimConfig

    path.write_text("[simulate]\npeople = 9\nframes = 50\n[simulate.detector]\ndropout = 0.2\n")
    assert read_sim(str(path), "clean", frames=30) == SimConfig.preset("clean", people=9, frames=30, dropout=0.2)
    assert read_sim(None) == SimConfig()


def test_check_of_a_fifo_a_folder_or_a_missing_file_is_one_line(tmp_path):
    import os

    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    for path, problem in ((fifo, "FIFO"), (tmp_path, "folder"), (tmp_path / "none.toml", "not found")):
        result = CliRunner().invoke(main, ["config", "--check", str(path)])
        assert result.exit_code == 2 and result.stderr.count("\n") == 1, result.output
        assert str(path) in result.stderr and problem in result.stderr, result.stderr
