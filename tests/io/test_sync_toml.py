"""sync.toml, read as an untrusted file: every malformed one is one line naming the file and the field."""
from __future__ import annotations

import os

import pytest

from mvm.errors import InputError
from mvm.io.sync_toml import read_sync_toml, write_sync_toml


def test_written_offsets_read_back(tmp_path):
    offsets = {"cam 1": 0, "cam_2": 4, "Cam-3": -3}
    write_sync_toml(tmp_path / "sync.toml", offsets)
    assert read_sync_toml(tmp_path / "sync.toml") == offsets


@pytest.mark.parametrize("text, field", [
    ("[offsets\ncam1 = 0", None),                           # not TOML
    ("cam1 = 0\n", "[offsets]"),                            # no table
    ("[offsets]\n", "[offsets]"),                           # an empty table
    ("[offsets]\ncam1 = 'three'\n", "[offsets].cam1"),
    ("[offsets]\ncam1 = 2.5\n", "[offsets].cam1"),
    ("[offsets]\ncam1 = true\n", "[offsets].cam1"),
    ("offsets = [1, 2]\n", "[offsets]"),
])
def test_a_malformed_file_is_one_line(tmp_path, text, field):
    path = tmp_path / "sync.toml"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        read_sync_toml(path)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(path))
    assert field is None or e.value.field == field


def test_a_fifo_or_a_folder_is_refused_without_reading(tmp_path):
    fifo = tmp_path / "sync.toml"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="sync.toml"):
        read_sync_toml(fifo)
    with pytest.raises(InputError, match="folder"):
        read_sync_toml(tmp_path)
