"""Cameras of every frame (paper Sec. 4.1) with pycolmap: SIFT features, sequential (or
exhaustive) matching, incremental mapping. Also imports of existing camera models.

Layout: ``SCENE/sfm/database.db`` (features and matches), ``SCENE/sfm/report.json`` (what was
registered, the reprojection error and the trajectory) and the model in ``SCENE/sparse``.
"""
from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mvm.core.config import check_settings, setting
from mvm.errors import InputError
from mvm.io.checks import load_json_object
from mvm.io.colmap import OPENCV_LENSES
from mvm.io.files import atomic_write_json
from mvm.io.images import check_frames, read_image
from mvm.io.layout import FRAMES, FRAMES_INDEX, SFM_DIR, SPARSE, SceneLayout
from mvm.io.outputs import atomic_replace_dir
from mvm.io.provenance import produce, read_record
from mvm.video.frames import list_frames

log = logging.getLogger(__name__)

#: The stage's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
SFM_STAGE = "the camera estimation"
#: COLMAP's camera models that the scene's reader takes (the pinholes and those with a lens of
#: OpenCV's models, :data:`mvm.io.colmap.OPENCV_LENSES`; the settings are checked without
#: importing pycolmap).
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", *OPENCV_LENSES)


@dataclass(frozen=True)
class SfmOptions:
    """Structure from motion (COLMAP)."""

    #: COLMAP camera model shared by all frames ("SIMPLE_RADIAL" for real video,
    #: "SIMPLE_PINHOLE" / "PINHOLE" for undistorted frames). [name]
    camera_model: str = setting("SIMPLE_RADIAL", choices=CAMERA_MODELS)
    #: Known focal length (the dataset's intrinsics); None lets COLMAP start from 1.2 × the
    #: image's larger side. [px]
    focal_px: float | None = setting(None, gt=0)
    #: Refine the focal length in bundle adjustment; with ``focal_px`` given and this off the
    #: intrinsics stay fixed. [bool]
    refine_focal: bool = True
    #: SIFT features per frame; fewer is faster, more registers hard frames. [features]
    max_features: int = setting(4096, ge=64, le=1_000_000)
    #: Frames are downscaled to this larger side for SIFT; lower is faster and finds fewer
    #: features. [px]
    max_image_size: int = setting(1600, ge=64, le=16384)
    #: Up to this many frames every pair is matched; above it, sequential matching of
    #: ``overlap`` neighbours. [frames]
    exhaustive_max_frames: int = setting(40, ge=0)
    #: Each frame is matched with this many following frames; more is slower and more robust. [frames]
    overlap: int = setting(10, ge=1)
    #: A COLMAP vocabulary tree file enabling loop detection in sequential matching; None: no
    #: loop detection. [path]
    vocab_tree: str | None = None
    #: CPU threads; -1: all. [threads]
    threads: int = setting(-1, ge=-1, le=4096)
    #: Random seed of the mapper. [1]
    seed: int = setting(0, ge=0, le=2**31 - 1)

    def __post_init__(self):
        check_settings(self)


@dataclass
class SfmReport:
    """What SfM produced: ``registered`` / ``unregistered`` frame names, the mean
    ``reprojection_error_px``, the ``focal_px`` of the shared camera, ``points`` in the
    model and ``centers: (V, 3)`` the trajectory (camera centres, in ``registered`` order)."""

    source: str
    registered: list[str]
    unregistered: list[str]
    reprojection_error_px: float
    focal_px: float
    points: int
    centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    seconds: dict = field(default_factory=dict)
    #: Why the cameras were made by this call (None: kept, up to date). Not written.
    why: str | None = field(default=None, compare=False)

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("why")
        d["centers"] = np.round(self.centers, 6).tolist()
        d["reprojection_error_px"] = (round(float(self.reprojection_error_px), 4)
                                      if np.isfinite(self.reprojection_error_px) else None)
        return d

    @classmethod
    def from_json(cls, d: dict) -> SfmReport:
        d = dict(d)
        d["centers"] = np.array(d.get("centers", []), dtype=float).reshape(-1, 3)
        if d.get("reprojection_error_px") is None:
            d["reprojection_error_px"] = float("nan")
        return cls(**d)


def _camera_params(model: str, focal: float, width: int, height: int) -> str:
    cx, cy = width / 2, height / 2
    params = {"SIMPLE_PINHOLE": [focal, cx, cy], "PINHOLE": [focal, focal, cx, cy],
              "SIMPLE_RADIAL": [focal, cx, cy, 0.0], "RADIAL": [focal, cx, cy, 0.0, 0.0],
              "OPENCV": [focal, focal, cx, cy, 0, 0, 0, 0]}
    if model not in params:
        raise ValueError(f"camera_model {model!r} with focal_px: expected one of {sorted(params)}")
    return ",".join(f"{p:g}" for p in params[model])


def _image_size(path: Path) -> tuple[int, int]:
    import cv2

    image = read_image(path, flags=cv2.IMREAD_UNCHANGED)
    return image.shape[1], image.shape[0]


def _extract_features(database: Path, frames_dir: Path, names: list[str], options: SfmOptions) -> None:
    """SIFT features of the frames ``names`` into ``database`` (one camera shared by all)."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = options.camera_model
    if options.focal_px is not None:
        w, h = _image_size(frames_dir / names[0])
        reader.camera_params = _camera_params(options.camera_model, options.focal_px, w, h)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu = False
    extraction.num_threads = options.threads
    extraction.max_image_size = options.max_image_size
    extraction.sift.max_num_features = options.max_features
    pycolmap.extract_features(database, frames_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)


def _match_features(database: Path, frames: int, options: SfmOptions) -> None:
    """Exhaustive matching up to ``options.exhaustive_max_frames`` frames, else sequential
    (with loop detection when a vocabulary tree is given)."""
    import pycolmap

    matching = pycolmap.FeatureMatchingOptions()
    matching.use_gpu = False
    matching.num_threads = options.threads
    if frames <= options.exhaustive_max_frames:
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
        return
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = options.overlap
    if options.vocab_tree:
        pairing.loop_detection = True
        pairing.vocab_tree_path = str(options.vocab_tree)
    pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing,
                              device=pycolmap.Device.cpu)


def _map(database: Path, frames_dir: Path, work: Path, options: SfmOptions,
         registered: Callable[[int], None] | None = None):
    """Incremental mapping -> the model that registers the most frames. ``registered(count)``
    after the initial pair and after each frame added to the model."""
    import pycolmap

    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = options.threads
    mapping.random_seed = options.seed
    mapping.ba_refine_focal_length = options.refine_focal or options.focal_px is None
    mapping.ba_refine_extra_params = options.camera_model not in ("SIMPLE_PINHOLE", "PINHOLE")
    mapping.multiple_models = False
    count = 0

    def added(frames: int) -> Callable[[], None]:
        def call() -> None:
            nonlocal count
            count += frames
            registered(count)
        return call

    callbacks = {"initial_image_pair_callback": added(2), "next_image_callback": added(1)} if registered else {}
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        models = pycolmap.incremental_mapping(database, frames_dir, tmp, mapping, **callbacks)
    if not models:
        raise InputError(frames_dir, None, "SfM found no model: too few matched features "
                                           "(more texture, more frames or a higher max_features)")
    return max(models.values(), key=lambda r: r.num_reg_images())


def sfm_inputs(scene: str | Path) -> dict[str, Path]:
    """What the cameras are estimated from (:mod:`mvm.io.provenance`): the frames and their index."""
    scene = Path(scene)
    return {FRAMES_INDEX: scene / FRAMES_INDEX, FRAMES: scene / FRAMES}


def sfm_settings(options: SfmOptions) -> dict:
    """The settings that shape the cameras (:mod:`mvm.io.provenance`; the thread count does not)."""
    settings = asdict(options)
    settings.pop("threads")                              # how fast, not what
    return {"source": "sfm", **settings}


def camera_inputs(scene: str | Path, cameras: str | Path | None = None,
                  options: SfmOptions | None = None) -> tuple[dict, dict]:
    """``(inputs, settings)`` of ``scene/sparse`` (:mod:`mvm.io.provenance`): made by SfM from
    the frames with ``options`` (``cameras`` None), imported from the COLMAP model ``cameras``
    (a folder; with the scene's ``frames.json``, which selects its images; nothing when it is
    ``scene/sparse`` itself), or from the camera file ``cameras`` and ``frames.json``."""
    scene = Path(scene)
    if cameras is None:
        return sfm_inputs(scene), sfm_settings(options or SfmOptions())
    if not Path(cameras).is_dir():
        return {"cameras": Path(cameras), FRAMES_INDEX: scene / FRAMES_INDEX}, {"source": "trajectory"}
    from mvm.io.colmap import find_model_dir

    if Path(cameras).resolve() == (scene / SPARSE).resolve():
        return {}, {"source": "colmap"}
    inputs = {"cameras": find_model_dir(Path(cameras))}
    if (scene / FRAMES_INDEX).is_file():
        inputs[FRAMES_INDEX] = scene / FRAMES_INDEX
    return inputs, {"source": "colmap"}


def _check_replaceable(scene: Path, settings: dict, force: bool) -> None:
    """Refuse to replace ``scene/sparse`` without ``force`` when mvm did not make it (a model
    imported by hand, a simulated scene's cameras), or when it holds imported cameras and
    ``settings`` ask for SfM's."""
    sparse = scene / SPARSE
    if force or not sparse.is_dir() or not any(sparse.iterdir()):
        return
    if not SceneLayout(scene).sfm_report.is_file():
        raise InputError(sparse, None, "a camera model mvm did not make: give --force to replace it, or "
                                       f"--cameras {sparse} to use it")
    before = (read_record(SceneLayout(scene).sfm_report) or {}).get("settings", {})
    if before.get("source") in ("colmap", "trajectory") and settings.get("source") == "sfm":
        origin = read_sfm_report(scene).source.split(":", 1)[-1]
        raise InputError(sparse, None, f"cameras imported from {origin}: give --force to replace them with SfM's, "
                                       f"or --cameras {origin} to keep them")


def _replace_model(scene: Path, write) -> None:
    """Put the model ``write(folder)`` makes in place of ``scene/sparse`` (the report's record
    already removed); its scale is SfM's again."""
    atomic_replace_dir(write, scene / SPARSE, replace_unmarked=True)
    SceneLayout(scene).scale_file.unlink(missing_ok=True)


def _model_made(scene: Path) -> bool:
    """Whether the cameras are there: the model and its report."""
    return SceneLayout(scene).sfm_report.is_file() and (scene / SPARSE).is_dir()


#: The stages of :func:`run_sfm` as its ``progress`` names them.
SFM_STAGES = ("sfm: features", "sfm: matching", "sfm: registered frames")


def run_sfm(scene: str | Path, options: SfmOptions = SfmOptions(), force: bool = False,
            progress: Callable[[str, int, int | None], None] | None = None) -> SfmReport:
    """Estimate the camera of every frame of ``scene/frames`` and write ``scene/sparse``.

    Kept when ``scene/sfm/report.json``'s record (``report.inputs.json``) says it was made from
    these frames with these options, unless ``force``; the report's ``why`` says why it was
    made again. A model in ``scene/sparse`` that mvm did not make, or imported cameras, is
    never replaced without ``force`` (one :class:`InputError` line). Frames that do not
    register are listed in the report and logged as a warning.
    ``progress(stage, done, total)``: each of :data:`SFM_STAGES` starts (0 done) and ends
    (total done; features and matching have no count in between), and the mapping counts
    every frame it registers out of the frames.
    """
    import pycolmap

    # COLMAP's own log follows this module's level: its INFO lines only with debug output
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 1
    scene = Path(scene)
    report_path = SceneLayout(scene).sfm_report
    settings = sfm_settings(options)
    _check_replaceable(scene, settings, force)
    report, _ = produce(report_path, SFM_STAGE, sfm_inputs(scene), settings,
                        lambda why, hashed: _estimate(scene, options, why, progress), lambda: read_sfm_report(scene),
                        force=force, exists=_model_made(scene))
    return report


def _estimate(scene: Path, options: SfmOptions, why: str, progress) -> SfmReport:
    """The body of :func:`run_sfm` once it decided to estimate the cameras (``why``): the model
    and the report written (the record is :func:`~mvm.io.provenance.produce`'s)."""
    import time

    log.info("%s: estimating the cameras: %s", scene, why)
    names = list_frames(scene)
    frames_dir = scene / FRAMES
    check_frames(frames_dir, names, root=scene)
    if len(names) < 2:
        raise InputError(frames_dir, None, f"need at least 2 frames for SfM, found {len(names)}")
    work = scene / SFM_DIR
    work.mkdir(parents=True, exist_ok=True)
    database = work / "database.db"
    database.unlink(missing_ok=True)
    seconds = {}
    features, matching, mapping = SFM_STAGES
    tell = progress or (lambda stage, done, total: None)
    t = time.perf_counter()
    tell(features, 0, None)
    _extract_features(database, frames_dir, names, options)
    tell(features, len(names), len(names))
    seconds["features"], t = time.perf_counter() - t, time.perf_counter()
    tell(matching, 0, None)
    _match_features(database, len(names), options)
    tell(matching, len(names), len(names))
    seconds["matching"], t = time.perf_counter() - t, time.perf_counter()
    tell(mapping, 0, len(names))
    rec = _map(database, frames_dir, work, options, lambda count: tell(mapping, count, len(names)))
    seconds["mapping"] = time.perf_counter() - t
    _replace_model(scene, lambda tmp: rec.write_binary(str(tmp)))
    report = _report(rec, names, "colmap")
    report.seconds = {k: round(v, 3) for k, v in seconds.items()}
    report.why = why
    _warn_unregistered(report, scene)
    document = report.to_json()
    document["options"] = asdict(options)
    atomic_write_json(SceneLayout(scene).sfm_report, document, pretty=True)
    return report


def _report(rec, names: list[str], source: str) -> SfmReport:
    """Summarize a pycolmap reconstruction against the frame ``names`` it was built from."""
    registered = {}
    for image in rec.images.values():
        if image.has_pose:
            registered[image.name] = -image.cam_from_world().rotation.matrix().T @ image.cam_from_world().translation
    order = [n for n in names if n in registered] + sorted(set(registered) - set(names))
    unregistered = [n for n in names if n not in registered]
    centers = np.array([registered[n] for n in order], dtype=float).reshape(-1, 3)
    focal = float(np.mean([c.mean_focal_length() for c in rec.cameras.values()])) if rec.cameras else float("nan")
    error = float(rec.compute_mean_reprojection_error()) if rec.num_points3D() else float("nan")
    return SfmReport(source, order, unregistered, error, focal, int(rec.num_points3D()), centers)


def _warn_unregistered(report: SfmReport, scene: Path) -> None:
    if report.unregistered:
        log.warning("%s: %d of %d frames did not register and are excluded: %s", scene,
                    len(report.unregistered), len(report.unregistered) + len(report.registered),
                    ", ".join(report.unregistered[:10]) + (" …" if len(report.unregistered) > 10 else ""))


def read_sfm_report(scene: str | Path) -> SfmReport:
    path = SceneLayout(scene).sfm_report
    if not path.exists():
        raise InputError(path, None, "file not found (run `mvm sfm` first)")
    data = load_json_object(path, root=scene, what="an SfM report object")
    data.pop("options", None)
    try:
        return SfmReport.from_json(data)
    except (TypeError, ValueError) as e:
        raise InputError(path, None, f"not an SfM report: {e}") from None


def import_colmap(model: str | Path, scene: str | Path, force: bool = False) -> SfmReport:
    """Copy an existing COLMAP model (text or binary, ``model`` or ``model/0``) into
    ``scene/sparse`` and write the report. Kept when already imported from this model's
    bytes (and the scene's ``frames.json``); the scene's own ``sparse/`` is read again every time
    (its bytes are the output's too); a model in ``scene/sparse`` that mvm did not make is
    not replaced without ``force``. With a ``frames.json``, the images of the model that are not
    among its frames (left out by the frame selection) are left out of the scene."""
    from mvm.io.colmap import find_model_dir

    scene = Path(scene)
    model_dir = find_model_dir(Path(model))
    in_place = Path(model).resolve() == (scene / SPARSE).resolve()
    inputs, settings = camera_inputs(scene, model)
    if not in_place:
        _check_replaceable(scene, settings, force)
    report_path = SceneLayout(scene).sfm_report
    report, _ = produce(report_path, SFM_STAGE, inputs, settings,
                        lambda why, hashed: _import_model(model_dir, scene, in_place, why),
                        lambda: read_sfm_report(scene), force=force or in_place, exists=_model_made(scene))
    return report


def _import_model(model_dir: Path, scene: Path, in_place: bool, why: str) -> SfmReport:
    """The body of :func:`import_colmap` once it decided to import ``model_dir`` (``why``)."""
    import pycolmap

    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises several types with C++ context
        raise InputError(model_dir, None,
                         f"cannot read COLMAP model: {str(e).splitlines()[0] if str(e) else e}") from None
    if not in_place:
        _keep_frames(rec, scene)
        _replace_model(scene, lambda tmp: rec.write_binary(str(tmp)))
    names = _frame_names_or(scene, sorted(i.name for i in rec.images.values()))
    report = _report(rec, names, f"colmap:{model_dir}")
    report.why = why
    _warn_unregistered(report, scene)
    atomic_write_json(SceneLayout(scene).sfm_report, report.to_json(), pretty=True)
    return report


def trajectory_frames(timestamps_s: np.ndarray, trajectory_us: np.ndarray, tolerance_s: float) -> np.ndarray:
    """Nearest trajectory line of every frame: ``timestamps_s: (F,)``, ``trajectory_us: (T,)``
    increasing -> ``(F,)`` indices, -1 where none lies within ``tolerance_s``."""
    t = np.asarray(trajectory_us, dtype=float) / 1e6
    j = np.clip(np.searchsorted(t, timestamps_s), 1, len(t) - 1)
    nearest = np.where(np.abs(t[j - 1] - timestamps_s) <= np.abs(t[j] - timestamps_s), j - 1, j)
    return np.where(np.abs(t[nearest] - timestamps_s) <= tolerance_s, nearest, -1)


def import_trajectory(path: str | Path, scene: str | Path, force: bool = False) -> SfmReport:
    """Cameras from a RealEstate10K / MannequinChallenge camera file (``mvm.io.trajectory``),
    matched to the frames of ``scene`` by timestamp (within half a frame), written to
    ``scene/sparse``. Frames without a line are excluded with a warning. Kept when already
    made from these bytes and frames; a model mvm did not make is not replaced without ``force``."""
    scene = Path(scene)
    inputs, settings = camera_inputs(scene, path)
    _check_replaceable(scene, settings, force)
    report_path = SceneLayout(scene).sfm_report
    report, _ = produce(report_path, SFM_STAGE, inputs, settings,
                        lambda why, hashed: _trajectory_model(Path(path), scene, why), lambda: read_sfm_report(scene),
                        force=force, exists=_model_made(scene))
    return report


def _trajectory_model(path: Path, scene: Path, why: str) -> SfmReport:
    """The body of :func:`import_trajectory` once it decided to match ``path``'s cameras (``why``)."""
    from mvm.core.scene import Cameras
    from mvm.io.colmap import write_colmap
    from mvm.io.trajectory import read_trajectory
    from mvm.video.frames import read_frame_index

    traj = read_trajectory(path)
    index = read_frame_index(scene)
    tolerance = 0.5 / index.fps if index.fps > 0 else 0.02
    line = trajectory_frames(index.timestamps, traj.timestamps_us, tolerance)
    ok = line >= 0
    if not ok.any():
        raise InputError(path, None, f"no timestamp matches a frame of {scene} (within {tolerance * 1e3:.0f} ms)")
    w, h = index.size
    fx, fy, cx, cy = (traj.intrinsics[line[ok]] * [w, h, w, h]).T
    V = int(ok.sum())
    K = np.zeros((V, 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = fx, fy, cx, cy, 1.0
    cameras = Cameras(K, traj.R[line[ok]], traj.t[line[ok]], np.broadcast_to([float(w), float(h)], (V, 2)).copy(),
                      tuple(n for n, k in zip(index.names, ok) if k))
    _replace_model(scene, lambda tmp: write_colmap(tmp, cameras))
    report = SfmReport(f"trajectory:{path}", list(cameras.names),
                       [n for n, k in zip(index.names, ok) if not k], float("nan"),
                       float(np.mean(cameras.focal)), 0, cameras.centers)
    report.why = why
    _warn_unregistered(report, scene)
    atomic_write_json(SceneLayout(scene).sfm_report, report.to_json(), pretty=True)
    return report


def _keep_frames(rec, scene: Path) -> None:
    """Deregister the images of ``rec`` (a pycolmap Reconstruction) that are not among the frames
    of ``scene/frames.json``, when it lists some of them (its images are then the scene's views)."""
    if not (scene / FRAMES_INDEX).is_file():
        return
    frames = set(list_frames(scene))
    drop = [image for image in rec.images.values() if image.name not in frames]
    if len(drop) < len(rec.images):
        for image in drop:
            if image.has_pose:
                rec.deregister_frame(image.frame_id)


def _frame_names_or(scene: Path, default: list[str]) -> list[str]:
    try:
        return list_frames(scene)
    except InputError:
        return default
