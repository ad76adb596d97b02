"""Model archives (``--model m.zip``) are unpacked into the cache and nowhere else: crafted zips
with names that climb out, absolute names, links, devices, too many or too large members are
refused before anything is written; a cache that cannot hold the model is one line."""
from __future__ import annotations

import errno
import os
import stat
import zipfile

import pytest

from mvm.errors import InputError
from mvm.io.files import OutputError
from mvm.video import models
from mvm.video.models import ModelSpec, onnx_in_zip, resolve_model

SPEC = ModelSpec("rtmo-s", "https://example.invalid/never.zip", (640, 640))
MODEL = b"onnx bytes " * 100


def _zip(path, members):
    """``members``: (name, data) or (ZipInfo, data)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members:
            z.writestr(name, data)
    return path


def _special(name, mode):
    info = zipfile.ZipInfo(name)
    info.external_attr = mode << 16
    return info


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "models"


@pytest.mark.parametrize("name, problem", [
    ("../victim.onnx", "'..'"), ("a/../../../victim_up.onnx", "'..'"), ("..\\victim.onnx", "'..'"),
    ("/tmp/abs_victim.onnx", "absolute"), ("C:/victim.onnx", "absolute"),
])
def test_names_that_leave_the_cache_are_refused_and_nothing_moves(tmp_path, cache, name, problem):
    zips = tmp_path / "zips"
    zips.mkdir()
    victim = zips / "victim.onnx"
    victim.write_bytes(b"precious")
    archive = _zip(zips / "m.zip", [("model/end2end.onnx", MODEL), (name, b"evil")] if "victim" in name
                   else [(name, b"evil")])
    with pytest.raises(InputError, match=problem) as e:
        resolve_model(SPEC, archive)
    assert "\n" not in str(e.value) and str(archive) in str(e.value)
    assert victim.read_bytes() == b"precious"
    assert _files(zips) == ["m.zip", "victim.onnx"] and _files(cache) == []


@pytest.mark.parametrize("mode, kind", [(stat.S_IFLNK | 0o777, "symbolic link"), (stat.S_IFCHR | 0o666, "character"),
                                        (stat.S_IFBLK | 0o666, "block"), (stat.S_IFIFO | 0o666, "FIFO")])
def test_links_and_special_members_are_refused(tmp_path, cache, mode, kind):
    archive = _zip(tmp_path / "m.zip", [(_special("model.onnx", mode), b"/etc/passwd")])
    with pytest.raises(InputError, match=kind):
        resolve_model(SPEC, archive)
    assert _files(cache) == []


def test_too_many_or_too_large_members_are_refused_before_unpacking(tmp_path, cache, monkeypatch):
    archive = _zip(tmp_path / "m.zip", [(f"f{i}.txt", b"") for i in range(12)] + [("m.onnx", MODEL)])
    monkeypatch.setattr(models, "MAX_ARCHIVE_MEMBERS", 10)
    with pytest.raises(InputError, match="13 members"):
        resolve_model(SPEC, archive)
    monkeypatch.setattr(models, "MAX_ARCHIVE_MEMBERS", 1000)
    monkeypatch.setattr(models, "MAX_MODEL_BYTES", len(MODEL) - 1)
    with pytest.raises(InputError, match=f"unpacks to {len(MODEL)} bytes"):
        resolve_model(SPEC, archive)
    assert _files(cache) == []


def test_a_member_larger_than_declared_is_refused(tmp_path, cache):
    archive = _zip(tmp_path / "m.zip", [("m.onnx", MODEL)])
    data = bytearray(archive.read_bytes())
    # the declared size in the central directory, then in the local header: one byte less
    for header, offset in ((b"PK\x01\x02", 24), (b"PK\x03\x04", 22)):
        at = data.index(header) + offset
        data[at:at + 4] = (len(MODEL) - 1).to_bytes(4, "little")
    archive.write_bytes(bytes(data))
    with pytest.raises(InputError, match="m.zip"):
        resolve_model(SPEC, archive)
    assert [p for p in _files(cache) if p.endswith(".onnx")] == []


def test_a_good_archive_unpacks_into_the_cache_even_from_a_read_only_folder(tmp_path, cache):
    zips = tmp_path / "zips"
    zips.mkdir()
    archive = _zip(zips / "m.zip", [("20231211/rtmo-s/end2end.onnx", MODEL), ("20231211/deploy.json", b"{}")])
    zips.chmod(0o555)
    try:
        onnx = resolve_model(SPEC, archive)
    finally:
        zips.chmod(0o755)
    assert onnx.read_bytes() == MODEL and cache in onnx.parents and onnx.name == "end2end.onnx"
    assert [p for p in _files(cache) if ".part" in p] == []
    assert resolve_model(SPEC, archive) == onnx                          # the second time: from the cache


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_cache_is_one_line(tmp_path, cache):
    archive = _zip(tmp_path / "m.zip", [("m.onnx", MODEL)])
    cache.mkdir(parents=True)
    cache.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="permission denied") as e:
            resolve_model(SPEC, archive)
    finally:
        cache.chmod(0o755)
    assert "\n" not in str(e.value)


def test_a_read_only_cache_folder_on_a_read_only_file_system_is_one_line(tmp_path, cache, monkeypatch):
    archive = _zip(tmp_path / "m.zip", [("m.onnx", MODEL)])

    def refuse(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(models.tempfile, "mkdtemp", refuse)
    with pytest.raises(OutputError, match="read-only file system"):
        resolve_model(SPEC, archive)


@pytest.mark.parametrize("blocker", ["file", "dangling"])
def test_a_file_or_dangling_link_in_place_of_the_cache_is_one_line(tmp_path, cache, blocker):
    archive = _zip(tmp_path / "m.zip", [("m.onnx", MODEL)])
    cache.parent.mkdir(parents=True)
    if blocker == "file":
        cache.write_bytes(b"not a folder")
    else:
        cache.symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputError, match="file is in the way" if blocker == "file" else "dangling") as e:
        resolve_model(SPEC, archive)
    assert str(cache) in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "nowhere").exists()


def test_a_full_disk_while_unpacking_leaves_nothing(tmp_path, cache, monkeypatch):
    archive = _zip(tmp_path / "m.zip", [("m.onnx", MODEL)])

    def full(out, block):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(models, "_write_block", full)
    with pytest.raises(OutputError, match="no space left") as e:
        resolve_model(SPEC, archive)
    assert "\n" not in str(e.value)
    assert [p for p in _files(cache) if p.endswith(".onnx") or ".part" in p] == []


@pytest.mark.parametrize("content, problem", [(b"not a zip", "not a valid zip"), (b"", "not a valid zip")])
def test_a_broken_archive_is_one_line(tmp_path, cache, content, problem):
    archive = tmp_path / "m.zip"
    archive.write_bytes(content)
    with pytest.raises(InputError, match=problem):
        onnx_in_zip(archive, cache / "m")


def test_a_fifo_as_model_is_refused_without_blocking(tmp_path, cache):
    os.mkfifo(tmp_path / "m.zip")
    with pytest.raises(InputError, match="FIFO"):
        resolve_model(SPEC, tmp_path / "m.zip")


def test_a_member_without_a_name_is_refused(tmp_path, cache):
    archive = _zip(tmp_path / "m.zip", [(zipfile.ZipInfo(""), b"x"), ("m.onnx", MODEL)])
    with pytest.raises(InputError, match="empty name"):
        resolve_model(SPEC, archive)


def test_a_cached_model_or_its_digest_that_is_not_a_regular_file_is_one_line(tmp_path):
    """A FIFO (or a folder) in the cache where a model or its ``.sha256`` should be never hangs
    the run: one line naming it."""
    import os

    from mvm.errors import InputError
    from mvm.video.models import verify_cached

    fifo = tmp_path / "model.onnx"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="model.onnx") as e:
        verify_cached(fifo)
    assert "\n" not in str(e.value)
    model = tmp_path / "other.onnx"
    model.write_bytes(b"weights")
    (tmp_path / "other.onnx.sha256").mkdir()
    with pytest.raises(InputError, match=r"other\.onnx\.sha256"):
        verify_cached(model)
