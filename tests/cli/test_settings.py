"""Every setting is checked when it is read (``--set``, ``--rig-set``, TOML files and each
command's options): one line naming the setting (and the file), exit status 2, before any work."""
from __future__ import annotations

import dataclasses
import json
import math

import pytest
from click.testing import CliRunner

from mvm.cli.main import main
from mvm.core.config import Bounds, Config, check_settings, setting, settings_from
from mvm.errors import InputError
from mvm.rig.options import RigOptions
from mvm.settings.tables import load_config

#: (arguments after ``mvm``, with ``{d}`` for a fresh folder; the exact line on stderr).
BAD = [
    (["reconstruct", "{d}/scene", "--set", "seed=-1"], "--set: seed: must be >= 0, got -1"),
    (["reconstruct", "{d}/scene", "--set", "ransac_hypotheses=1000000000"],
     "--set: ransac_hypotheses: must be <= 10000, got 1000000000"),
    (["reconstruct", "{d}/scene", "--set", "tau=nan"], "--set: tau: expected float, got nan"),
    (["reconstruct", "{d}/scene", "--set", "gamma=inf"], "--set: gamma: must be finite, got inf"),
    (["reconstruct", "{d}/scene", "--set", "min_views=1.5"], "--set: min_views: expected int, got 1.5"),
    (["reconstruct", "{d}/scene", "--set", "keypoint_threshold=2"], "--set: keypoint_threshold: must be <= 1, got 2.0"),
    (["reconstruct", "{d}/scene", "--set", "tau"], "--set: tau: expected KEY=VALUE"),
    (["demo", "-o", "{d}/demo", "--set", "lock_timeout_s=-inf"], "--set: lock_timeout_s: must be finite, got -inf"),
    (["demo", "-o", "{d}/demo", "--seed", "-1"], "--seed: must be >= 0, got -1"),
    (["demo", "-o", "{d}/demo", "--people", "0"], "--people: must be >= 1, got 0"),
    (["simulate", "{d}/sim", "--arc", "nan"], "--arc: expected float, got nan"),
    (["simulate", "{d}/sim", "--arc", "1e400"], "--arc: must be finite, got inf"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--width", "0"], "--width: must be >= 16, got 0"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--width", "-5"], "--width: must be >= 16, got -5"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--width", "100000"], "--width: must be <= 16384, got 100000"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--max-frames", "-1"], "--max-frames: must be >= 1, got -1"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--max-frames", "1e3"], "--max-frames: expected int, got '1e3'"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--rate", "nan"], "--rate: expected float, got nan"),
    (["frames", "{d}/clip.mp4", "-o", "{d}/scene", "--blur-ratio", "inf"], "--blur-ratio: must be finite, got inf"),
    (["run", "{d}/clip.mp4", "-o", "{d}/scene", "--import", "{d}/x.json", "--focal", "-1"],
     "--focal: must be > 0, got -1.0"),
    (["batch", "{d}/root", "--rate", "0"], "--rate: must be > 0, got 0.0"),
    (["batch", "{d}/root", "--set", "seed=-1"], "--set: seed: must be >= 0, got -1"),
    (["overlay", "{d}/scene", "--fps", "nan"], "--fps: expected float, got nan"),
    (["predict", "{d}/a.png", "--checkpoint", "{d}/c.pt", "--focal", "inf"], "--focal: must be finite, got inf"),
    (["export", "{d}/scene", "--out", "{d}/ds", "--min-keypoints", "18"], "--min-keypoints: must be <= 17, got 18"),
    (["rig", "reconstruct", "{d}/rig", "--frame-rate", "inf"], "--frame-rate: must be finite, got inf"),
    (["rig", "reconstruct", "{d}/rig", "--frame-rate", "0"], "--frame-rate: must be > 0, got 0.0"),
    (["rig", "reconstruct", "{d}/rig", "--smoothing", "butterworth", "--frame-rate", "10", "--rig-set", "cutoff_hz=6"],
     "--rig-set: cutoff_hz: must be below half the frame rate (5 Hz at frame_rate 10), got 6"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "smoothing=butterworth", "--rig-set", "cutoff_hz=20"],
     "--rig-set: cutoff_hz: must be below half the frame rate (15 Hz at frame_rate 30), got 20"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "cutoff_hz=inf"], "--rig-set: cutoff_hz: must be finite, got inf"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "savgol_window=1"],
     "--rig-set: savgol_window: must be >= 3, got 1"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "savgol_window=8"], "--rig-set: savgol_window: must be odd, got 8"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "up=x"],
     "--rig-set: up: expected one of '+z', '-z', '+y', '-y', got 'x'"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "seed=1"],
     "--rig-set: seed: not taken by --rig-set of mvm rig reconstruct: give it with --set"),
    (["rig", "reconstruct", "{d}/rig", "--set", "batch_size=8"],
     "--set: batch_size: not taken by --set of mvm rig reconstruct: give it with --rig-set"),
    (["rig", "reconstruct", "{d}/rig", "--set", "video_order=false"],
     "--set: video_order: not used by mvm rig reconstruct"),
    (["rig", "reconstruct", "{d}/rig", "--rig-set", "frame_rat=25"], "--rig-set: frame_rat: not a setting of mvm rig "
     "reconstruct (known: batch_size, bone_weight, cutoff_hz, filter_order, frame_rate, max_gap, "
     "max_interpolation_gap, max_link_distance_m, metres_per_unit, min_link_joints, min_track_length, "
     "occlusion_inferred_gap, occlusion_max_gap, savgol_window, smoothing, trc_inferred, up, workers)"),
    (["rig", "reconstruct", "{d}/rig", "--set", "refine_max_iterations=0"],
     "--set: refine_max_iterations: must be >= 1, got 0"),
]


#: A ``--set`` key the command does not take: (arguments after ``mvm``, the command named).
UNUSED = [(["reconstruct", "{d}/scene", "--set", "batch_size=3"], "mvm reconstruct"),
          (["demo", "-o", "{d}/demo", "--set", "people=3"], "mvm demo"),
          (["batch", "{d}/root", "--set", "max_frames=3"], "mvm batch"),
          (["rig", "reconstruct", "{d}/rig", "--set", "frames=3"], "mvm rig reconstruct"),
          (["train", "{d}/train.toml", "--set", "tau=0.3"], "mvm train")]


@pytest.mark.parametrize("args, command", UNUSED)
def test_a_set_key_the_command_does_not_use_is_refused(tmp_path, args, command):
    key = args[-1].split("=")[0]
    result = CliRunner().invoke(main, [a.format(d=tmp_path) for a in args])
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith(f"mvm: error: --set: {key}: not a setting of {command} (known: ")
    assert result.stderr.count("\n") == 1 and not any(tmp_path.iterdir())


@pytest.mark.parametrize("args, line", BAD, ids=[" ".join(a[0:1] + a[2:]).replace("{d}/", "") for a, _ in BAD])
def test_bad_setting_is_one_line_before_any_work(tmp_path, args, line):
    before = sorted(tmp_path.rglob("*"))
    result = CliRunner().invoke(main, [a.format(d=tmp_path) for a in args])
    assert result.exit_code == 2, result.output
    assert result.stderr == f"mvm: error: {line}\n"
    assert sorted(tmp_path.rglob("*")) == before                        # nothing written, nothing created


#: (a settings file's text, the line after its name).
BAD_FILES = [("seed = -1", "seed: must be >= 0, got -1"),
             ("[reconstruct]\nransac_hypotheses = 1e9", "ransac_hypotheses: must be <= 10000, got 1000000000"),
             ("min_parallax_deg = inf", "min_parallax_deg: must be finite, got inf"),
             ("distance_scale = nan", "distance_scale: expected float, got nan"),
             ("seed = 99999999999999999999", "seed: must be <= 9223372036854775807, got 99999999999999999999")]


@pytest.mark.parametrize("command", [["reconstruct", "{d}/scene"], ["rig", "reconstruct", "{d}/rig"], ["batch", "{d}"]])
@pytest.mark.parametrize("text, line", BAD_FILES)
def test_bad_setting_in_a_file_names_the_file(tmp_path, command, text, line):
    (tmp_path / "settings.toml").write_text(text)
    args = [a.format(d=tmp_path) for a in command] + ["--config", str(tmp_path / "settings.toml")]
    result = CliRunner().invoke(main, args)
    assert (result.exit_code, result.stderr) == (2, f"mvm: error: {tmp_path / 'settings.toml'}: {line}\n")


def test_set_overrides_a_file_and_is_named_when_bad(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text("tau = 0.4\nseed = 3\n")
    assert load_config(path, {"seed": 5}) == Config(tau=0.4, seed=5)
    with pytest.raises(InputError) as info:
        load_config(path, {"seed": -5})
    assert str(info.value) == "--set: seed: must be >= 0, got -5"


def test_settings_are_checked_however_they_are_made():
    """The library API checks too: a dataclass built or replaced in code refuses a bad value."""
    with pytest.raises(InputError, match="^seed: must be >= 0, got -1$"):
        Config(seed=-1)
    with pytest.raises(InputError, match="^tau: expected float, got nan$"):
        Config().replace(tau=math.nan)
    with pytest.raises(InputError, match="^refine: expected bool, got 'yes'$"):
        Config(refine="yes")
    with pytest.raises(InputError, match="^cutoff_hz: must be below half the frame rate"):
        RigOptions(smoothing="butterworth", frame_rate=10.0, cutoff_hz=6.0)
    assert RigOptions(smoothing="butterworth", frame_rate=10.0).cutoff == 2.0   # by default it follows the frame rate
    assert RigOptions(smoothing="savgol", frame_rate=10.0, cutoff_hz=6.0).cutoff_hz == 6.0   # only butterworth uses it
    assert Config() == Config(**{f.name: f.default for f in dataclasses.fields(Config)})


def test_every_default_is_allowed_and_every_number_field_is_bounded():
    for cls in (Config, RigOptions):
        check_settings(cls())
        for field in dataclasses.fields(cls):
            if field.type in ("int", "float"):
                bounds = field.metadata["bounds"]
                assert bounds.ge is not None or bounds.gt is not None, f"{cls.__name__}.{field.name} has no lower bound"


def test_the_mechanism_on_a_new_settings_class():
    @dataclasses.dataclass(frozen=True)
    class Options:
        rate: float = setting(2.0, gt=0, le=10)
        label: str = setting("a", choices=("a", "b"))
        window: int | None = setting(None, ge=3, odd=True)
        ratio: float = 0.5                                           # no bounds: still finite

        def __post_init__(self):
            check_settings(self)

        def implied_problems(self):
            return [("window", "needs a rate of at least 4")] if self.window and self.rate < 4 else []

    assert settings_from(Options, {"rate": "5", "window": "5"}, "opts.toml") == Options(5.0, "a", 5)
    cases = [({"rate": "0"}, "opts.toml: rate: must be > 0, got 0.0"),
             ({"rate": "11"}, "opts.toml: rate: must be <= 10, got 11.0"),
             ({"label": "c"}, "opts.toml: label: expected one of 'a', 'b', got 'c'"),
             ({"window": "4", "rate": 5}, "opts.toml: window: must be odd, got 4"),
             ({"window": "5"}, "opts.toml: window: needs a rate of at least 4"),
             ({"ratio": "inf"}, "opts.toml: ratio: must be finite, got inf"),
             ({"other": 1}, "opts.toml: other: unknown setting (known: label, rate, ratio, window)")]
    for values, line in cases:
        with pytest.raises(InputError) as info:
            settings_from(Options, values, "opts.toml")
        assert str(info.value) == line
    assert settings_from(Options, {"window": "none"}, "x").window is None
    assert Bounds(ge=1).problem(0) == "must be >= 1, got 0" and Bounds(ge=1).problem(1) is None


def test_a_scene_records_the_settings_in_effect_once(tmp_path):
    """poses3d.json holds the settings the scene ran with: those left to the driver resolved
    (a scene: the association in 3D, no completion), each once."""
    runner = CliRunner()
    scene = tmp_path / "scene"
    simulated = runner.invoke(main, ["simulate", str(scene), "--preset", "clean", "--people", "2", "--frames", "20"])
    assert simulated.exit_code == 0, simulated.output
    for args, association in (([], "3d"), (["--set", "association=paper"], "paper")):
        result = runner.invoke(main, ["reconstruct", str(scene), "--no-refine", *args])
        assert result.exit_code == 0, result.output
        text = (scene / "mvm" / "poses3d.json").read_text()
        assert text.count('"association"') == 1 and text.count('"complete"') == 1
        config = json.loads(text)["config"]
        assert (config["association"], config["complete"], config["refine"]) == (association, False, False)
