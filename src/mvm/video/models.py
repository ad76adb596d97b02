"""Published ONNX models of the 2D pose detectors and the local cache that holds them.

A model is a local file (``--model PATH``: an ``.onnx`` file, or the published ``.zip`` that
holds one) or a URL (the model's published one, or ``--model URL``: :func:`url_spec`),
downloaded on first use into the cache folder: ``$MVM_CACHE/models`` when ``MVM_CACHE`` is
set, else ``$XDG_CACHE_HOME/mvm/models`` (by default ``~/.cache/mvm/models``). A download is
verified against the model's SHA-256 when it is known, and its SHA-256 is recorded beside it
(``NAME.sha256``) and checked at every later use, so a corrupted cache is found; it is written
atomically: an interrupted or corrupted download leaves no file behind. Offline, the error names
the file to fetch and where to put it. (The 8 hex digits in OpenMMLab's ONNX file names are those
of the PyTorch checkpoint, not of the zip.)

The URLs are the ones RTMLib (``rtmlib.tools.solution.body.Body``) uses.
"""
from __future__ import annotations

import hashlib
import logging
import os
import re
import shutil
import stat
import tempfile
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.error import URLError
from urllib.request import urlopen

from mvm.errors import InputError
from mvm.io.checks import check_input_file, read_text
from mvm.io.files import OutputError, atomic_output, make_dir, output_error

log = logging.getLogger(__name__)

_DRIVE = re.compile(r"^[A-Za-z]:")
_MMPOSE = "https://download.openmmlab.com/mmpose/v1/projects"


@dataclass(frozen=True)
class ModelSpec:
    """A published model: ``url`` of its zip (holding one ``.onnx``), the network's input
    ``size`` (width, height) in pixels, the input normalization (None: raw 0-255 BGR) and the
    zip's SHA-256 when it is published (None: recorded at the first download, checked after)."""

    name: str
    url: str
    size: tuple[int, int]
    mean: tuple[float, float, float] | None = None
    std: tuple[float, float, float] | None = None
    sha256: str | None = None
    #: The file's name in the cache (None: the last part of ``url``, as a published model's).
    file: str | None = None


_IMAGENET = {"mean": (123.675, 116.28, 103.53), "std": (58.395, 57.12, 57.375)}

#: RTMLib's three modes: the model sizes each detector uses.
MODES = ("lightweight", "balanced", "performance")

#: RTMO (one-stage, bottom-up) body models trained on Body7, COCO-17 keypoints.
RTMO = {
    "lightweight": ModelSpec("rtmo-s", f"{_MMPOSE}/rtmo/onnx_sdk/rtmo-s_8xb32-600e_body7-640x640-dac2bf74_20231211.zip",
                   (640, 640)),
    "balanced": ModelSpec("rtmo-m", f"{_MMPOSE}/rtmo/onnx_sdk/rtmo-m_16xb16-600e_body7-640x640-39e78cc4_20231211.zip",
                   (640, 640)),
    "performance": ModelSpec("rtmo-l", f"{_MMPOSE}/rtmo/onnx_sdk/"
                   "rtmo-l_16xb16-600e_body7-640x640-b37118ce_20231211.zip", (640, 640)),
}
#: RTMPose (top-down) body models trained on Body7, COCO-17 keypoints.
RTMPOSE = {
    "lightweight": ModelSpec("rtmpose-s", f"{_MMPOSE}/rtmposev1/onnx_sdk/"
                   "rtmpose-s_simcc-body7_pt-body7_420e-256x192-acd4a1ef_20230504.zip", (192, 256), **_IMAGENET),
    "balanced": ModelSpec("rtmpose-m", f"{_MMPOSE}/rtmposev1/onnx_sdk/"
                   "rtmpose-m_simcc-body7_pt-body7_420e-256x192-e48f03d0_20230504.zip", (192, 256), **_IMAGENET),
    "performance": ModelSpec("rtmpose-x", f"{_MMPOSE}/rtmposev1/onnx_sdk/"
                   "rtmpose-x_simcc-body7_pt-body7_700e-384x288-71d7b7e9_20230629.zip", (288, 384), **_IMAGENET),
}
#: YOLOX person detectors (trained on HumanArt) that give RTMPose its boxes.
YOLOX = {
    "lightweight": ModelSpec("yolox-tiny", f"{_MMPOSE}/rtmposev1/onnx_sdk/yolox_tiny_8xb8-300e_humanart-6f3252f9.zip",
                   (416, 416)),
    "balanced": ModelSpec("yolox-m", f"{_MMPOSE}/rtmposev1/onnx_sdk/yolox_m_8xb8-300e_humanart-c2c7a14a.zip",
                   (640, 640)),
    "performance": ModelSpec("yolox-x", f"{_MMPOSE}/rtmposev1/onnx_sdk/yolox_x_8xb8-300e_humanart-a39d44ed.zip",
                   (640, 640)),
}


def is_url(model: str | Path | None) -> bool:
    """Whether ``--model`` names a model to download (``https://`` or ``http://``) rather than a file."""
    return isinstance(model, str) and model.lower().startswith(("https://", "http://"))


#: The longest file name of a model URL (before its digest and suffix). [characters]
MAX_STEM = 120


def url_spec(url: str, size: tuple[int, int] = (640, 640)) -> ModelSpec:
    """A model given by its URL (an ``.onnx`` or a ``.zip`` holding one) as a :class:`ModelSpec`:
    downloaded into the cache on first use like a published model, its SHA-256 recorded then
    and checked at every later use. The cached file is named after the URL's path and a digest of
    the whole URL (``yolo11n-pose-1a2b3c4d5e6f.onnx``): two URLs ending in the same name are two
    files, and a query or a path ending in ``/`` or ``..`` names no file outside the cache. A URL
    whose path names no ``.onnx`` or ``.zip`` file is refused in one line.

    >>> url_spec("https://example.org/m/yolo.onnx?download=true").file.startswith("yolo-")
    True
    """
    from urllib.parse import unquote, urlsplit

    name = unquote(urlsplit(url).path).rsplit("/", 1)[-1]
    stem, dot, suffix = name.rpartition(".")
    if not dot or suffix.lower() not in ("onnx", "zip") or not stem.strip(". ") or "\\" in name:
        raise InputError(None, "--model", f"{url}: expected the URL of an .onnx model or a .zip holding one")
    if not stem.isprintable() or len(stem) > MAX_STEM:
        raise InputError(None, "--model", f"{url}: the file name of the URL is not printable, or longer than "
                                          f"{MAX_STEM} characters")
    digest = hashlib.sha256(url.encode()).hexdigest()[:12]
    return ModelSpec(stem, url, size, file=f"{stem}-{digest}.{suffix.lower()}")


def cache_path(spec: ModelSpec) -> Path:
    """Where the download of ``spec`` is kept: :func:`cache_dir` / its ``file`` (a URL's, named by
    :func:`url_spec`), else / the last part of its published URL."""
    return cache_dir() / (spec.file or spec.url.rsplit("/", 1)[-1])


def cache_dir() -> Path:
    """The folder downloaded models are kept in: ``$MVM_CACHE/models``, else
    ``$XDG_CACHE_HOME/mvm/models`` (``~/.cache/mvm/models``)."""
    if os.environ.get("MVM_CACHE"):
        return Path(os.environ["MVM_CACHE"]).expanduser() / "models"
    base = os.environ.get("XDG_CACHE_HOME") or "~/.cache"
    return Path(base).expanduser() / "mvm" / "models"


def sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file (a regular file of bounded size, :func:`mvm.io.checks.check_input_file`,
    else an :class:`InputError`: a FIFO or a device in the cache never hangs the run)."""
    digest = hashlib.sha256()
    with open(check_input_file(path), "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def download(url: str, target: str | Path, expected_sha256: str | None = None,
             progress: Callable[[int, int], None] | None = None, timeout_s: float = 60.0,
             option: str = "--model") -> Path:
    """Download ``url`` to ``target`` atomically (a temporary file in the same folder, renamed
    once complete and verified). ``expected_sha256``: the file's SHA-256 (or its leading hex
    digits); the digest is also written to ``target.sha256``. Raises :class:`InputError` naming
    the URL and the target when the download fails or the checksum differs; no file is left at
    ``target`` or beside it then."""
    target = Path(target)
    digest = hashlib.sha256()
    with atomic_output(target, suffix=".part") as tmp:          # renamed over target once verified
        try:
            with open(tmp, "wb") as out, urlopen(url, timeout=timeout_s) as response:
                total = int(response.headers.get("Content-Length") or 0)
                done = 0
                for block in iter(lambda: response.read(1 << 20), b""):
                    out.write(block)
                    digest.update(block)
                    done += len(block)
                    if done > MAX_MODEL_BYTES:
                        raise InputError(url, None, f"more than {MAX_MODEL_BYTES} bytes: not a model; the file was "
                                                    "not kept")
                    if progress:
                        progress(done, total)
                if total and done != total:
                    raise InputError(url, None, f"download interrupted after {done} of {total} bytes; "
                                                f"fetch it by hand into {target}")
                out.flush()
                os.fsync(out.fileno())
        except InputError:
            raise
        except (URLError, OSError, ValueError) as e:
            reason = getattr(e, "reason", None) or e
            raise InputError(url, None, f"cannot download ({reason}): fetch this file and put it at {target}, "
                                        f"or pass its path with {option}") from None
        if expected_sha256 and not digest.hexdigest().startswith(expected_sha256.lower()):
            raise InputError(url, None, f"checksum mismatch: SHA-256 {digest.hexdigest()[:16]}… is not "
                                        f"{expected_sha256[:16]}…; the file was not kept")
        _sidecar(target).write_text(digest.hexdigest() + "\n")
    return target


def _sidecar(path: Path) -> Path:
    return path.with_name(path.name + ".sha256")


def verify_cached(path: Path, expected_sha256: str | None = None) -> str:
    """The SHA-256 of a cached file, checked against ``expected_sha256`` and the digest
    recorded at its download; a mismatch is an :class:`InputError` that says to delete it."""
    digest = sha256(path)
    sidecar = _sidecar(path)
    recorded = read_text(sidecar).strip() if sidecar.exists() or sidecar.is_symlink() else None
    for want in (expected_sha256, recorded):
        if want and not digest.startswith(want.lower()):
            raise InputError(path, None, f"checksum mismatch (SHA-256 {digest[:16]}…, expected {want[:16]}…): "
                                         "the cached file is corrupt; delete it to download it again")
    return digest


MAX_ARCHIVE_MEMBERS = 1000
"""The most members a model zip may hold (a published one holds a handful)."""
MAX_MODEL_BYTES = 4 * 2 ** 30
"""The most bytes a model zip may unpack to, all members together (a published one: < 300 MB)."""

_SPECIAL_MEMBERS = ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISCHR, "a character device"),
                    (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                    (stat.S_ISSOCK, "a socket"))


def _member_problem(info: zipfile.ZipInfo) -> str | None:
    """Why the zip member ``info`` may not be unpacked, or None: an empty or absolute name, a name
    with a ``..`` component, a symbolic link, a device or another special file."""
    name = info.filename
    if not name.strip("/"):
        return "an empty name"
    posix = name.replace("\\", "/")
    if "\x00" in name or posix.startswith("/") or _DRIVE.match(posix):
        return "an absolute name (members are unpacked below the cache folder)"
    if ".." in posix.split("/"):
        return "a '..' in the name leads outside the cache folder"
    mode = info.external_attr >> 16
    for test, kind in _SPECIAL_MEMBERS:
        if mode and test(mode):
            return f"{kind}, not a regular file"
    return None


def _cache_folder(folder: Path) -> Path:
    """``folder`` (created) when it can hold an extracted model; OutputError naming it otherwise."""
    for parent in (*reversed(folder.parents), folder):
        if parent.is_symlink() and not parent.exists():
            raise OutputError(parent, None, "cannot write: a dangling symbolic link is in the way of the cache folder")
        if parent.exists() and not parent.is_dir():
            raise OutputError(parent, None, "cannot write: a file is in the way of the cache folder")
    return make_dir(folder)


def _write_block(out, block: bytes) -> None:
    out.write(block)


def _unpack(z: zipfile.ZipFile, info: zipfile.ZipInfo, target: Path) -> None:
    """Copy the member ``info`` to the new file ``target``, at most its declared size (the
    CRC is checked by :mod:`zipfile` as the last block is read)."""
    done = 0
    with z.open(info) as source, open(target, "xb") as out:
        for block in iter(lambda: source.read(1 << 20), b""):
            done += len(block)
            if done > info.file_size:
                raise zipfile.BadZipFile(f"{info.filename} unpacks to more than its declared {info.file_size} bytes")
            _write_block(out, block)
        out.flush()
        os.fsync(out.fileno())
    if done != info.file_size:
        raise zipfile.BadZipFile(f"{info.filename} unpacks to {done} bytes, not its declared {info.file_size}")


def onnx_in_zip(archive: Path, folder: Path | None = None) -> Path:
    """The ``.onnx`` file of a published zip, extracted (once) into ``folder`` (default: beside
    the zip, named as it) -> its path.

    The archive is checked before anything is unpacked: every member must have a relative name
    without ``..``, be a regular file or folder (no link, device or FIFO), the members must be
    at most :data:`MAX_ARCHIVE_MEMBERS` and unpack to at most :data:`MAX_MODEL_BYTES`. The model
    is unpacked to a temporary folder inside ``folder``'s parent (the same file system), checked
    against its declared size and CRC, then renamed into ``folder``: nothing outside the cache is
    written or moved, and a failure leaves no partial file. A refused archive raises one
    :class:`InputError` line; a cache that cannot be written, one :class:`OutputError` line."""
    archive = check_input_file(archive)
    folder = folder or archive.with_suffix("")
    found = sorted(folder.rglob("*.onnx")) if folder.is_dir() and not folder.is_symlink() else []
    if found:
        return found[0]
    try:
        with zipfile.ZipFile(archive) as z:
            infos = z.infolist()
            if len(infos) > MAX_ARCHIVE_MEMBERS:
                raise InputError(archive, None, f"{len(infos)} members, more than the {MAX_ARCHIVE_MEMBERS} "
                                                "a model archive may hold")
            for info in infos:
                problem = _member_problem(info)
                if problem:
                    raise InputError(archive, info.filename[:200], f"refusing to unpack: {problem}")
            total = sum(info.file_size for info in infos)
            if total > MAX_MODEL_BYTES:
                raise InputError(archive, None, f"unpacks to {total} bytes, more than the {MAX_MODEL_BYTES} "
                                                "a model archive may")
            members = [i for i in infos if not i.is_dir() and i.filename.lower().endswith(".onnx")]
            if not members:
                raise InputError(archive, None, "the archive holds no .onnx model")
            member = members[0]
            name = member.filename.replace("\\", "/").rsplit("/", 1)[-1]
            _cache_folder(folder.parent)
            try:
                tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".part", dir=folder.parent))
            except OSError as e:
                raise output_error(folder.parent, e) from None
            try:
                _unpack(z, member, tmp / name)
                _cache_folder(folder)
                target = folder / name
                os.replace(tmp / name, target)
            except OSError as e:
                raise output_error(folder, e) from None
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    except InputError:
        raise
    except zipfile.BadZipFile as e:
        raise InputError(archive, None, f"not a valid zip archive: {e}") from None
    except (OSError, EOFError, ValueError, RuntimeError, NotImplementedError, zlib.error) as e:
        raise InputError(archive, None, f"cannot unpack: {str(e).splitlines()[0] if str(e) else type(e).__name__}") \
            from None
    return target


def model_problem(spec: ModelSpec | None, path: str | Path | None = None, download_ok: bool = True,
                  option: str = "--model") -> str | None:
    """What is wrong with a model before any work, in a phrase naming ``option`` (None: nothing
    known): a given file that is missing or not a regular file, a published model neither in
    the cache nor allowed to be fetched (``spec`` may be None when ``path`` is given). Reads
    nothing but the file's status."""
    if path is not None:
        path = Path(path)
        if not path.exists() and not path.is_symlink():
            return f"{option}: model file not found"
        try:
            check_input_file(path)
        except InputError as e:
            return f"{option}: {e.problem}"
        return None
    archive = cache_path(spec)
    if not archive.is_file() and not download_ok:
        return f"{option}: model not in the cache: fetch {spec.url} and put it at {archive}, or give {option} PATH"
    return None


def resolve_model(spec: ModelSpec | None, path: str | Path | None = None, download_ok: bool = True,
                  progress: Callable[[int, int], None] | None = None, option: str = "--model") -> Path:
    """The local ``.onnx`` file of a model: ``path`` when given (an ``.onnx``, or the published
    ``.zip``, extracted into the cache), else the cached download of ``spec.url`` (fetched now unless ``download_ok`` is
    false, in which case a missing file is an :class:`InputError` naming what to fetch).
    ``option``: the command-line option that gives ``path``, named in the errors."""
    problem = model_problem(spec, path, download_ok, option)
    if problem is not None:
        raise InputError(path if path is not None else cache_path(spec), None, problem)
    if path is not None:
        path = Path(path)
        check_input_file(path)
        if path.suffix.lower() != ".zip":
            return path
        return onnx_in_zip(path, cache_dir() / f"{path.stem}-{sha256(path)[:12]}")
    archive = cache_path(spec)
    if not archive.is_file():
        log.info("downloading %s to %s", spec.url, archive)
        download(spec.url, archive, spec.sha256, progress, option=option)
    else:
        verify_cached(archive, spec.sha256)
    return archive if archive.suffix.lower() == ".onnx" else onnx_in_zip(archive)
