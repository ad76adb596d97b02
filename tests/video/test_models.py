"""The model cache: downloads from a local file:// URL (checksum good, bad, an interrupted
download), the cache folder, the offline message, and models given as a published zip."""
from __future__ import annotations

import hashlib
import zipfile

import pytest

from mvm.errors import InputError
from mvm.video import models
from mvm.video.models import ModelSpec, cache_dir, download, resolve_model, verify_cached


@pytest.fixture
def published(tmp_path):
    """A published-style zip holding one .onnx, served from a file:// URL."""
    server = tmp_path / "server"
    server.mkdir()
    archive = server / "rtmo-s_body7-640x640-dac2bf74_20231211.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("20231211/rtmo-s/end2end.onnx", b"onnx bytes " * 1000)
    return archive, archive.as_uri(), hashlib.sha256(archive.read_bytes()).hexdigest()


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def test_cache_dir_follows_mvm_cache_then_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine" / "models"
    monkeypatch.delenv("MVM_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "mvm" / "models"


def test_download_with_good_checksum_then_cached(published, tmp_path, monkeypatch):
    archive, url, digest = published
    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    spec = ModelSpec("rtmo-s", url, (640, 640), sha256=digest)
    onnx = resolve_model(spec)
    assert onnx.read_bytes() == b"onnx bytes " * 1000 and onnx.name == "end2end.onnx"
    cached = tmp_path / "cache" / "models" / archive.name
    assert cached.read_bytes() == archive.read_bytes()
    assert (cached.parent / (archive.name + ".sha256")).read_text().strip() == digest
    archive.unlink()                                                  # offline now: the cache answers
    assert resolve_model(spec) == onnx


def test_bad_checksum_keeps_nothing(published, tmp_path):
    _, url, _ = published
    target = tmp_path / "cache" / "model.zip"
    with pytest.raises(InputError, match="checksum mismatch"):
        download(url, target, "0" * 64)
    assert _leftovers(target.parent) == []


def test_interrupted_download_keeps_nothing(published, tmp_path, monkeypatch):
    _, url, _ = published
    real = models.urlopen

    class Broken:
        def __init__(self, response):
            self.response, self.headers, self.calls = response, response.headers, 0

        def read(self, n):
            self.calls += 1
            if self.calls > 1:
                raise ConnectionResetError("connection reset by peer")
            return self.response.read(100)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.response.close()

    monkeypatch.setattr(models, "urlopen", lambda u, timeout: Broken(real(u, timeout=timeout)))
    target = tmp_path / "cache" / "model.zip"
    with pytest.raises(InputError) as info:
        download(url, target)
    assert str(target) in str(info.value) and "\n" not in str(info.value)
    assert _leftovers(target.parent) == []


def test_offline_names_the_file_and_where_to_put_it(tmp_path, monkeypatch):
    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    spec = ModelSpec("rtmo-s", (tmp_path / "nowhere" / "rtmo.zip").as_uri(), (640, 640))
    with pytest.raises(InputError) as info:
        resolve_model(spec)
    message = str(info.value)
    assert spec.url in message and str(tmp_path / "cache" / "models" / "rtmo.zip") in message
    with pytest.raises(InputError, match="fetch"):
        resolve_model(spec, download_ok=False)
    assert _leftovers(tmp_path / "cache" / "models") == []


def test_a_corrupted_cache_is_found(published, tmp_path, monkeypatch):
    archive, url, _ = published
    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    spec = ModelSpec("rtmo-s", url, (640, 640))                      # no published checksum: recorded
    resolve_model(spec)
    cached = tmp_path / "cache" / "models" / archive.name
    cached.write_bytes(cached.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(InputError, match="corrupt"):
        verify_cached(cached)


def test_local_model_zip_or_onnx(published, tmp_path, monkeypatch):
    archive, _, _ = published
    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    spec = ModelSpec("rtmo-s", "https://example.invalid/never.zip", (640, 640))
    onnx = resolve_model(spec, archive)
    assert onnx.name == "end2end.onnx" and (tmp_path / "cache") in onnx.parents
    assert _leftovers(archive.parent) == [archive.name]                 # nothing written beside it
    onnx = tmp_path / "m.onnx"
    onnx.write_bytes(b"x")
    assert resolve_model(spec, onnx) == onnx
    with pytest.raises(InputError, match="not found"):
        resolve_model(spec, tmp_path / "missing.onnx")


def test_a_model_url_names_one_cache_file_of_its_own():
    """A URL's cached file is its path's name plus a digest of the whole URL: a query string is no
    part of the suffix, two URLs ending in the same name are two files, and a URL whose path names
    no .onnx or .zip (a folder, ``..``) is refused in one line."""
    from mvm.video.models import url_spec

    a = url_spec("https://one.example/m/yolo.onnx?download=true")
    b = url_spec("https://two.example/x/yolo.onnx")
    assert a.file.startswith("yolo-") and a.file.endswith(".onnx") and "?" not in a.file
    assert b.file.startswith("yolo-") and a.file != b.file
    assert url_spec("https://one.example/m/Pose.ZIP").file.endswith(".zip")
    for bad in ("https://one.example/m/", "https://one.example/m/..", "https://one.example/m/model.pt",
                "https://one.example/m/a%00b.onnx", "https://one.example/m/a%0Ab.onnx",
                "https://one.example/m/" + "x" * 300 + ".onnx"):
        with pytest.raises(InputError, match="--model"):
            url_spec(bad)


def test_two_model_urls_of_one_name_are_two_files_of_the_cache(published, tmp_path, monkeypatch):
    """What a URL downloads is the file its spec names: two URLs ending in the same name (another
    path to the same file, and another file) download to files of their own in the cache."""
    from mvm.video.models import cache_path, url_spec

    monkeypatch.setenv("MVM_CACHE", str(tmp_path / "cache"))
    zip_path, url, _ = published
    other = tmp_path / "elsewhere" / zip_path.name
    other.parent.mkdir()
    other.write_bytes(zip_path.read_bytes())
    twin = zip_path.parent.as_uri() + "/./" + zip_path.name
    specs = [url_spec(url), url_spec(twin), url_spec(other.as_uri())]
    paths = [resolve_model(spec) for spec in specs]
    assert len({cache_path(spec) for spec in specs}) == 3
    assert all(cache_path(spec).is_file() and cache_path(spec).parent == tmp_path / "cache" / "models"
               for spec in specs)
    assert all(p.suffix == ".onnx" and p.is_file() for p in paths)


def test_a_download_past_the_model_size_is_refused_and_not_kept(published, tmp_path, monkeypatch):
    _, url, _ = published
    monkeypatch.setattr(models, "MAX_MODEL_BYTES", 1000)
    target = tmp_path / "cache" / "model.zip"
    with pytest.raises(InputError, match="more than 1000 bytes"):
        download(url, target)
    assert _leftovers(target.parent) == []
