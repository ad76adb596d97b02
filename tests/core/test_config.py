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
