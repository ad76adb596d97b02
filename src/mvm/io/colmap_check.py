"""Check the files of a COLMAP model before pycolmap reads them.

pycolmap trusts the counts and lengths in a model: a binary file truncated inside an image
name, or a count of 2^32 records, makes it loop for hours, and a text ``frames.txt`` with a
huge ``NUM_DATA_IDS`` does the same. So every file is walked here first, with each count
checked against the bytes (or tokens) that remain, and the values mvm relies on are checked
too: known camera models with the right number of finite parameters, positive image sizes
and focal lengths, finite non-zero quaternions, finite translations and points, image names
that are UTF-8, unique and relative (:mod:`mvm.io.paths`), and ids that refer to something.

Layouts: COLMAP's ``src/colmap/scene/reconstruction_io_{binary,text}.cc`` (3.12+, with
``rigs`` and ``frames``; older models without them are read too). Every problem raises one
:class:`~mvm.errors.InputError`: ``FILE: FIELD: PROBLEM`` where FIELD is ``line N`` in a
text file and the record (``image 3``, ``camera 1``…) in a binary one.
"""
from __future__ import annotations

from pathlib import Path

from mvm.errors import InputError
from mvm.io.checks import read_bytes
from mvm.io.colmap_binary_check import BINARY_CHECKS
from mvm.io.colmap_records import FILES, OPTIONAL_FILES, ModelRecords
from mvm.io.colmap_text_check import TEXT_CHECKS


def model_format(model_dir: Path) -> str:
    """``"bin"`` or ``"txt"``: the format pycolmap will read from ``model_dir``."""
    for ext in ("bin", "txt"):
        if all((model_dir / f"{name}.{ext}").is_file() for name in FILES):
            return ext
    ext = "bin" if (model_dir / "cameras.bin").is_file() else "txt"
    missing = [f"{name}.{ext}" for name in FILES if not (model_dir / f"{name}.{ext}").is_file()]
    raise InputError(model_dir, None, f"incomplete COLMAP model: missing {', '.join(missing)}")



def model_files(model_dir: str | Path) -> tuple[str, dict[str, bytes]]:
    """The format of the COLMAP model in ``model_dir`` (``bin``/``txt``) and the content of
    each of its files, in the order they are checked: ``{"cameras": b"...", ...}`` (the
    optional ``rigs`` and ``frames`` where present). Files are read the guarded way
    (:func:`mvm.io.checks.read_bytes`)."""
    model_dir = Path(model_dir)
    ext = model_format(model_dir)
    files = {}
    for name in OPTIONAL_FILES[:1] + FILES[:1] + OPTIONAL_FILES[1:] + FILES[1:]:
        path = model_dir / f"{name}.{ext}"
        if name in OPTIONAL_FILES and not (path.exists() or path.is_symlink()):
            continue
        files[name] = read_bytes(path)
    return ext, files


def check_model(model_dir: str | Path, files: tuple[str, dict[str, bytes]] | None = None) -> ModelRecords:
    """Check every file of the COLMAP model in ``model_dir``; return what the checks collected
    (:class:`~mvm.io.colmap_records.ModelRecords`). ``files``: what :func:`model_files` read of
    it, else it is read here."""
    model_dir = Path(model_dir)
    ext, content = files or model_files(model_dir)
    model = ModelRecords()
    check = BINARY_CHECKS if ext == "bin" else TEXT_CHECKS
    for name, data in content.items():
        check[name](data, model_dir / f"{name}.{ext}", model)
    rigs, frames = (name in content for name in OPTIONAL_FILES)
    if rigs != frames:
        have, need = ("rigs", "frames") if rigs else ("frames", "rigs")
        raise InputError(model_dir / f"{need}.{ext}", None,
                         f"missing: a model with {have}.{ext} (COLMAP 3.12 layout) needs {need}.{ext} too")
    for image_id, (where, _) in model.frame_images.items():
        if image_id not in model.image_ids:
            raise InputError(model.frames, where, f"image {image_id} is not in images.{ext}")
    return model
