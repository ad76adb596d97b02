"""The configuration object: TOML, overrides and validation."""
from __future__ import annotations

import pytest

from mvm.core.config import Config
from mvm.errors import InputError
from mvm.settings.tables import load_config


def test_toml_and_overrides(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[reconstruct]\ntau = 0.3\nrefine = false\nmin_views = 3\n")
    config = load_config(path, {"gamma": "2.5"})
    assert config == Config(tau=0.3, refine=False, min_views=3, gamma=2.5)


@pytest.mark.parametrize("text, message", [
    ("tau = 'high'", "tau: expected float, got 'high'"),
    ("unknown_key = 1", "unknown_key: unknown setting"),
    ("min_views = 1", "min_views: must be >= 2"),
    ("gamma = -1.0", "gamma: must be > 0"),
    ("tau = [", "not valid TOML"),
    ("refine = 3", "refine: expected bool"),
])
def test_bad_config_names_file_and_key(tmp_path, text, message):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_config(path)
    assert str(path) in str(info.value) and message in str(info.value)


def test_settings_are_resolved_once_at_the_drivers_entry(tmp_path):
    """A driver resolves the settings left to it at its entry; the steps below it refuse settings
    left unresolved rather than resolve them again, perhaps as another driver would."""
    from mvm.core.pipeline import triangulate_poses
    from mvm.rig.reconstruct_rig import completion_prior, instants_config, rig_config
    from mvm.scenes import reconstruct_read

    assert not Config().resolved and not Config(association="paper").resolved
    assert Config().for_driver("scene").resolved and rig_config().resolved
    assert rig_config() == Config().for_driver("rig") and instants_config(rig_config()).refine is False
    with pytest.raises(AssertionError, match="rig_config"):
        instants_config(Config())
    with pytest.raises(AssertionError, match="rig_config"):
        completion_prior(Config())
    with pytest.raises(AssertionError, match="resolved"):
        triangulate_poses(None, None, Config())
    with pytest.raises(AssertionError, match="scene_config"):
        reconstruct_read(tmp_path, Config())
