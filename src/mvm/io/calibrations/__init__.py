"""Calibrations made by other systems, converted into the project's
:class:`~mvm.io.calib_toml.RigCalibration` (then written as Calib.toml).

One module per format (or family); :data:`FORMATS` maps each format's name to its reader, a
function ``read(path, binning=1.0) -> RigCalibration`` whose result is in mvm's conventions
(world -> camera, OpenCV camera axes, metres). :func:`detect_format` tells the format from the
file's name, then from its first bytes; :func:`read_foreign_calibration` reads one.

==========  ==========================================================  =========================
format      recognised by                                               module
==========  ==========================================================  =========================
qualisys    ``*.qca.txt`` / ``*.qca``, or XML ``<calibration>``           :mod:`.qualisys`
vicon       ``*.xcp``, or XML ``<Cameras>``                              :mod:`.vicon`
easymocap   ``intri.yml`` / ``extri.yml``, or a folder with both         :mod:`.easymocap`
opencap     ``*.pickle``, or a folder of them                            :mod:`.opencap`
anipose     a ``*.toml`` of ``[cam_*]`` tables with ``name`` (aniposelib) :mod:`.toml_family`
freemocap   the same layout (``--format freemocap`` to say so)           :mod:`.toml_family`
caliscope   a ``*.toml`` whose ``[cam_*]`` tables have ``port``          :mod:`.toml_family`
biocv       ``*.calib``, or a folder of them                             :mod:`.biocv`
==========  ==========================================================  =========================
"""
from __future__ import annotations

import importlib
from pathlib import Path

from mvm.errors import InputError

#: Format name -> ``(module, reader)``, the reader ``(path, binning=1.0) -> RigCalibration``;
#: imported when used, so that the names cost nothing to list (``mvm rig calibrate --help``).
FORMATS: dict[str, tuple[str, str]] = {
    "qualisys": ("qualisys", "read_qualisys"), "vicon": ("vicon", "read_vicon"),
    "easymocap": ("easymocap", "read_easymocap"), "opencap": ("opencap", "read_opencap"),
    "anipose": ("toml_family", "read_anipose"), "freemocap": ("toml_family", "read_freemocap"),
    "caliscope": ("toml_family", "read_caliscope"), "biocv": ("biocv", "read_biocv")}

#: EasyMocap's two files, bioCV's file type.
EASYMOCAP_FILES, BIOCV_SUFFIX = ("intri.yml", "extri.yml"), ".calib"
_HEAD_BYTES = 4096


def reader(fmt: str):
    """The reader function of the format ``fmt`` (a key of :data:`FORMATS`)."""
    if fmt not in FORMATS:
        raise InputError(None, "--format", f"unknown calibration format {fmt!r}; known: {', '.join(FORMATS)}")
    module, name = FORMATS[fmt]
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


def _detect_folder(folder: Path) -> str:
    if any((folder / name).is_file() for name in EASYMOCAP_FILES):
        return "easymocap"
    if any(folder.glob("*.pickle")) or any(folder.glob("*/*.pickle")):
        return "opencap"
    if any(folder.glob(f"*{BIOCV_SUFFIX}")):
        return "biocv"
    raise InputError(folder, None, f"no calibration recognised in this folder ({', '.join(EASYMOCAP_FILES)}, "
                                   f"*.pickle, *{BIOCV_SUFFIX}): name the file, or the format with --format")


def detect_format(path: str | Path) -> str:
    """The format of the calibration at ``path`` (a file, or the folder of a per-camera set):
    by its name first (module docstring), then by its content (XML root, TOML tables); none
    recognised raises :class:`InputError` listing the formats."""
    from mvm.io.calibrations.toml_family import is_caliscope
    from mvm.io.checks import load_toml, read_bytes

    path = Path(path)
    if path.is_dir():
        return _detect_folder(path)
    name = path.name.lower()
    by_name = [("qualisys", (".qca.txt", ".qca")), ("vicon", (".xcp",)), ("opencap", (".pickle", ".pkl")),
               ("biocv", (BIOCV_SUFFIX,))]
    for fmt, suffixes in by_name:
        if name.endswith(suffixes):
            return fmt
    if name in EASYMOCAP_FILES:
        return "easymocap"
    head = read_bytes(path)[:_HEAD_BYTES].lstrip()
    if head.startswith(b"<"):
        if b"<calibration" in head:
            return "qualisys"
        if b"<Cameras" in head:
            return "vicon"
    if name.endswith(".toml"):
        return "caliscope" if is_caliscope(load_toml(path)) else "anipose"
    raise InputError(path, None, "calibration format not recognised (by name or content): name it with --format "
                                 f"({', '.join(FORMATS)})")


def source_files(path: str | Path, fmt: str) -> list[Path]:
    """Every file the reader of ``fmt`` reads for the calibration at ``path``: EasyMocap's two
    files, bioCV's and OpenCap's file per camera, else ``path`` itself (what an output must not
    replace)."""
    if fmt == "easymocap":
        from mvm.io.calibrations.easymocap import easymocap_files
        return list(easymocap_files(path))
    if fmt in ("biocv", "opencap"):
        module = importlib.import_module(f"{__name__}.{fmt}")
        return list(getattr(module, f"{fmt}_files")(path).values())
    return [Path(path)]


def read_foreign_calibration(path: str | Path, fmt: str | None = None, binning: float = 1.0):
    """The :class:`~mvm.io.calib_toml.RigCalibration` at ``path`` in the format ``fmt`` (None:
    :func:`detect_format`), converted to mvm's conventions; ``binning``: Qualisys's binning
    factor (1: full resolution; other formats refuse any other value). Its ``metadata`` records
    the source and the method."""
    fmt = fmt or detect_format(path)
    read = reader(fmt)
    if binning != 1 and fmt != "qualisys":
        raise InputError(None, "--binning", f"applies to Qualisys calibrations, not {fmt} (got {binning:g})")
    return read(path, binning=binning)
