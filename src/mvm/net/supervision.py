"""Supervision for the monocular network: refined 3D poses projected into every frame.

Every person's 3D joints are projected into every view of its scene, giving 2D keypoints and
each keypoint's *relative* depth: its camera z divided by the median camera z of all labelled
joints of that view (an SfM reconstruction has no metric scale, so only depth ratios are
meaningful, Section 5 of the paper). One reference per image keeps who stands in front of whom,
which the paper's image-level depth loss learns. The result is a COCO keypoints dataset with two extra
per-keypoint fields, ``keypoint_depths`` (17 floats, 0 where missing) and ``has_3d`` (17 flags),
that many scenes merge into.
"""
from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from mvm.core.camera import project_persons
from mvm.core.completion import INFERRED, complete_persons
from mvm.core.keypoints import NUM_JOINTS
from mvm.core.scene import Persons3D, Scene
from mvm.errors import InputError
from mvm.io.checks import check_input_file, read_bytes
from mvm.io.coco import annotation_record, empty_dataset
from mvm.io.coco_dataset import read_coco_dataset
from mvm.io.files import atomic_write_bytes, atomic_write_json, make_dir
from mvm.io.layout import DEFAULT_OUTPUT, FRAMES, POSES3D, SUPERVISION_FILE, SceneLayout
from mvm.io.outputs import atomic_replace_dir, check_output_location

LOG = logging.getLogger(__name__)

LINK_MODES = ("symlink", "copy", "none")
#: The export's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
EXPORT_STAGE = "the export"


def export_inputs(scene_dirs: Iterable[str | Path], output: str = DEFAULT_OUTPUT, frames: bool = False,
                  located: bool = False) -> dict[str, object]:
    """What a dataset exported from ``scene_dirs`` is made from (:mod:`mvm.io.provenance`):
    each scene's ``<output>/poses3d.json`` and what it was reconstructed from (``poses2d.json``,
    ``sparse/``), and its ``frames/`` when ``frames`` (they are copied into the dataset). One
    scene's inputs have bare names (``poses3d.json``); several scenes' are prefixed with their
    folder, and their order (which numbers the images) is an input too. ``located``: so is where
    each scene is (a dataset outside the scenes names its images after their folders and links
    to them there: a scene moved or renamed is exported again)."""
    from mvm.io.scene_dir import reconstruction_inputs

    scene_dirs = [Path(s) for s in scene_dirs]
    inputs: dict[str, object] = {}
    for scene in scene_dirs:
        prefix = "" if len(scene_dirs) == 1 else f"{scene.as_posix()}/"
        layout = SceneLayout(scene, output)
        these = {POSES3D: layout.poses3d, **reconstruction_inputs(scene)}
        if frames:
            these[FRAMES] = layout.frames
        inputs.update({prefix + name: path for name, path in these.items()})
    if located or len(scene_dirs) > 1:
        inputs["scenes"] = [(s.resolve() if located else s).as_posix() for s in scene_dirs]
    return inputs


def export_settings(link: str, min_keypoints: int, complete: bool, out: str) -> dict:
    """The settings the record of an exported data set keeps (:mod:`mvm.io.provenance`): how
    the frames get in, the fewest labelled joints of an annotation, whether unseen joints are
    completed, and where the data set is (its relative links and file names depend on it):
    ``out``, its absolute path, or for a data set inside its one scene (``mvm batch``'s), its
    path in the scene (the two move together)."""
    return {"link": link, "min_keypoints": int(min_keypoints), "complete": bool(complete), "out": out}


def unreconstructed_boxes(scene: Scene, persons: Persons3D, view: int) -> np.ndarray:
    """Boxes ``(M, 4)`` (``x0, y0, x1, y1``) of the 2D poses of ``view`` that no reconstructed
    person holds (``persons.members``: annotation ids): people MVM saw but did not reconstruct,
    which training must ignore rather than learn as background."""
    poses = scene.poses
    held = np.concatenate([np.asarray(m, dtype=int).reshape(-1) for m in persons.members] + [np.zeros(0, int)])
    rows = np.nonzero((poses.view == view) & ~np.isin(poses.ids, held))[0]
    kp = poses.keypoints[rows]
    vis = kp[..., 2] > 0
    rows, kp, vis = rows[vis.sum(1) >= 2], kp[vis.sum(1) >= 2], vis[vis.sum(1) >= 2]
    lo = np.where(vis[..., None], kp[..., :2], np.inf).min(1)
    hi = np.where(vis[..., None], kp[..., :2], -np.inf).max(1)
    margin = 0.1 * (hi - lo)                                  # joints span less than the body
    return np.concatenate([lo - margin, hi + margin], axis=1).reshape(-1, 4)


def ignore_record(ann_id: int, image_id: int, box: np.ndarray) -> dict:
    """A person without keypoints (COCO's ``num_keypoints: 0``): its box is ignored in training
    and in OKS evaluation. ``box: (4,)`` ``x0, y0, x1, y1``."""
    x0, y0, x1, y1 = (float(v) for v in box)
    return {"id": int(ann_id), "image_id": int(image_id), "category_id": 1, "keypoints": [0] * (3 * NUM_JOINTS),
            "num_keypoints": 0, "bbox": [round(x0, 2), round(y0, 2), round(x1 - x0, 2), round(y1 - y0, 2)],
            "area": round((x1 - x0) * (y1 - y0), 2), "iscrowd": 0}


def _as_item(item) -> tuple[Scene, Persons3D, Path | None]:
    if not isinstance(item, (tuple, list)) or len(item) not in (2, 3):
        raise InputError(None, "scenes_and_persons",
                         "expected (Scene, Persons3D) or (Scene, Persons3D, frames_dir) items")
    scene, persons = item[0], item[1]
    frames = Path(item[2]) if len(item) == 3 and item[2] is not None else None
    if not isinstance(scene, Scene) or not isinstance(persons, Persons3D):
        raise InputError(None, "scenes_and_persons",
                         f"expected (Scene, Persons3D), got ({type(scene).__name__}, {type(persons).__name__})")
    return scene, persons, frames


def export_supervision(scenes_and_persons: Iterable, out_dir: str | Path, link: str = "symlink",
                       min_keypoints: int = 3, prior=None, finish: Callable[[Path], None] | None = None) -> Path:
    """Write a COCO-style supervision dataset of several scenes; returns the annotation file.

    Args:
        scenes_and_persons: ``(Scene, Persons3D)`` or ``(Scene, Persons3D, frames_dir)`` items;
            ``frames_dir`` holds the scene's images under their camera names.
        out_dir: the dataset directory: ``annotations.json`` and, unless ``link='none'``,
            ``images/<scene>/<frame>``.
        link: ``'symlink'`` or ``'copy'`` the frames into ``out_dir``; ``'none'`` leaves them
            where they are (``file_name`` then points at them, relative to ``out_dir`` when a
            ``frames_dir`` is given, else ``<scene>/<frame>``).
        min_keypoints: persons with fewer labelled joints in a view get no annotation there.
        prior: a :class:`mvm.core.prior.PosePrior`: joints the persons lack are inferred from it
            first (:func:`mvm.core.completion.complete_persons`). Whenever the persons carry
            flags (from completion here or in ``poses3d.json``), every annotation carries them as
            ``keypoint_flags`` ("observed", "interpolated", "inferred"; "missing" where not labelled).
        finish: called with the annotation file once it is written, before the data set is put
            in place (a record of its inputs written there arrives with it, in the same swap).
    """
    if link not in LINK_MODES:
        raise InputError(None, "link", f"expected one of {', '.join(LINK_MODES)}, got {link!r}")
    out_dir = Path(out_dir)
    items = [_as_item(item) for item in scenes_and_persons]
    check_output_location(out_dir, [frames for _, _, frames in items if frames is not None])

    def build(tmp: Path) -> None:
        _write_dataset(items, out_dir, tmp, link, min_keypoints, prior)
        if finish is not None:
            finish(tmp / SUPERVISION_FILE)

    atomic_replace_dir(build, out_dir)
    return out_dir / SUPERVISION_FILE


def _write_dataset(items: list, out_dir: Path, tmp: Path, link: str, min_keypoints: int, prior=None) -> None:
    """Fill ``tmp`` (which becomes ``out_dir``) with the dataset of ``items``."""
    data = empty_dataset("mvm supervision: refined 3D poses projected into every frame")
    names_seen: dict[str, int] = {}
    image_id = ann_id = 0
    for scene, persons, frames in items:
        flags = persons.flags
        if prior is not None and len(persons):
            X, new = complete_persons(persons.keypoints3d, prior)
            flags = np.where(new == INFERRED, INFERRED, new if flags is None else flags)
            persons = dataclasses.replace(persons, keypoints3d=X, flags=flags)
        label = _unique(scene.name or "scene", names_seen)
        cams = scene.cameras
        n_ann = 0
        for v in range(len(cams)):
            kp, dep = project_persons(persons.keypoints3d, cams.K[v], cams.R[v], cams.t[v], cams.size[v])
            keep = np.nonzero((kp[:, :, 2] > 0).sum(1) >= min_keypoints)[0]
            name = cams.names[v]
            image_id += 1
            data["images"].append({"id": image_id, "file_name": _place_frame(name, label, frames, out_dir, tmp, link),
                                   "width": int(cams.size[v, 0]), "height": int(cams.size[v, 1]),
                                   "scene": label, "frame": name})
            for p in keep:
                ann_id += 1
                data["annotations"].append(annotation_record(ann_id, image_id, kp[p], dep[p], person_id=int(p),
                                                             flags=None if flags is None else flags[p]))
                n_ann += 1
            for box in unreconstructed_boxes(scene, persons, v):
                ann_id += 1
                data["annotations"].append(ignore_record(ann_id, image_id, box))
        LOG.info("scene %s: %d frames, %d annotations", label, len(cams), n_ann)
    atomic_write_json(tmp / SUPERVISION_FILE, data)


def _unique(name: str, seen: dict[str, int]) -> str:
    if name not in seen:
        seen[name] = 0
        return name
    seen[name] += 1
    return f"{name}_{seen[name]}"


def _place_frame(name: str, scene: str, frames: Path | None, out_dir: Path, tmp: Path, link: str) -> str:
    """Link or copy one frame into ``tmp/images/<scene>/`` (``tmp`` becomes ``out_dir``);
    returns its ``file_name``. The frame must be a regular file inside its scene directory
    (``frames``' parent) once links are resolved (:func:`mvm.io.checks.check_input_file`)."""
    if link == "none":
        if frames is None:
            return f"{scene}/{name}"
        return os.path.relpath(frames / name, out_dir)
    if frames is None:
        raise InputError(None, "frames_dir", f"scene {scene}: link={link!r} needs the directory of its frames")
    src = frames / name
    if not (src.exists() or src.is_symlink()):
        raise InputError(src, None, "frame not found")
    check_input_file(src, root=frames.parent)
    rel = Path("images") / scene / name
    dst = tmp / rel
    make_dir(dst.parent)
    if link == "symlink":
        # tmp and out_dir are siblings: the relative link reads the same from either
        dst.symlink_to(os.path.relpath(src.resolve(), (out_dir / rel).parent.resolve()))
    else:
        atomic_write_bytes(dst, read_bytes(src, root=frames.parent))
    return rel.as_posix()


def _source_dataset(path: Path) -> tuple[list[dict], list[dict]]:
    """The images and annotations of one supervision file, checked by
    :func:`mvm.io.coco_dataset.read_coco_dataset`."""
    data = read_coco_dataset(path).document
    return data["images"], data["annotations"]


def merge_datasets(paths: Iterable[str | Path], out: str | Path,
                   on_bad_source: Callable[[Path, InputError], None] | None = None) -> Path:
    """Merge COCO keypoint files into ``out`` with fresh unique ids.

    ``file_name`` of every image is rewritten relative to ``out``'s directory, so the frames
    are found from the merged file as they were from each source. A source that cannot be
    read or is inconsistent raises :class:`InputError`; with ``on_bad_source`` it is reported
    to that callback and left out instead, and the others are merged.
    """
    out = Path(out)
    merged = empty_dataset("mvm supervision: merged")
    image_id = ann_id = 0
    for path in paths:
        path = Path(path)
        try:
            images, annotations = _source_dataset(path)
        except InputError as e:
            if on_bad_source is None:
                raise
            on_bad_source(path, e)
            continue
        remap = {}
        for image in images:
            image_id += 1
            remap[image["id"]] = image_id
            full = path.parent / image["file_name"]
            merged["images"].append({**image, "id": image_id,
                                     "file_name": Path(os.path.relpath(full, out.parent)).as_posix()})
        for ann in annotations:
            ann_id += 1
            merged["annotations"].append({**ann, "id": ann_id, "image_id": remap[ann["image_id"]]})
    atomic_write_json(out, merged)
    return out
