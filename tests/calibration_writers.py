"""Known cameras written by hand in the published layouts of other systems' calibration files
(Qualisys .qca.txt, Vicon .xcp, EasyMocap intri/extri.yml, OpenCap pickles, anipose TOML,
caliscope config.toml, bioCV text files), for the converters' tests."""
from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation


@dataclass
class KnownCamera:
    """A camera in mvm's conventions: world -> camera ``R`` (3, 3), ``t`` (3,) metres."""

    name: str
    K: np.ndarray
    dist: np.ndarray          # (5,) k1 k2 p1 p2 k3
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    @property
    def P(self) -> np.ndarray:
        return self.K @ np.hstack([self.R, self.t[:, None]])


def _n(value) -> str:
    """A number as text, exactly."""
    return repr(float(value))


def known_cameras(n: int = 3, seed: int = 0) -> list[KnownCamera]:
    """``n`` cameras on a ring 4 m around the origin, 1.5 m up, looking at it, each with its
    own focal lengths, principal point and lens."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.3
        center = np.array([4 * np.cos(a), 4 * np.sin(a), 1.5])
        z = -center / np.linalg.norm(center)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])                     # rows: camera axes in the world
        fx = 1400 + 100 * rng.random()
        K = np.array([[fx, 0.0, 950 + 20 * rng.random()], [0.0, fx * 1.001, 530 + 20 * rng.random()],
                      [0.0, 0.0, 1.0]])
        dist = np.array([-0.1, 0.05, 0.001, -0.002, 0.01]) * (1 + rng.random())
        cams.append(KnownCamera(f"cam{i + 1:02d}", K, dist, R, -R @ center, (1920, 1080)))
    return cams


def write_qca(path: Path, cams: list[KnownCamera], left: int = 8, top: int = 4, binning: int = 1,
              extra: str = "") -> Path:
    """A QTM ``.qca.txt``: intrinsics in 1/64 pixel of a sensor ``binning`` times the video's
    resolution, the video window at (``left``, ``top``), poses in mm in QTM's camera axes."""
    parts = ['<?xml version="1.0" encoding="UTF-8"?>', '<calibration source="test" type="regular">', "  <cameras>"]
    for c in cams:
        M = np.diag([1.0, -1.0, -1.0]) @ c.R                     # OpenCV's axes -> QTM's (y up, along -z)
        x, y, z = c.center * 1000
        w, h = c.size[0] * binning, c.size[1] * binning
        k1, k2, p1, p2, k3 = c.dist
        rot = " ".join(f'r{i + 1}{j + 1}="{_n(M[i, j])}"' for i in range(3) for j in range(3))
        parts += [f'    <camera active="1" avg-residual="0.4" model="Miqus Video" serial="{c.name}" viewrotation="0">',
                  f'      <fov_video left="{left}" top="{top}" right="{left + w - 1}" bottom="{top + h - 1}"/>',
                  f'      <transform x="{_n(x)}" y="{_n(y)}" z="{_n(z)}" {rot}/>',
                  f'      <intrinsic focalLengthU="{_n(c.K[0, 0] * binning * 64)}" '
                  f'focalLengthV="{_n(c.K[1, 1] * binning * 64)}" '
                  f'centerPointU="{_n((c.K[0, 2] * binning + left) * 64)}" '
                  f'centerPointV="{_n((c.K[1, 2] * binning + top) * 64)}" skew="0" '
                  f'radialDistortion1="{_n(k1)}" radialDistortion2="{_n(k2)}" radialDistortion3="{_n(k3)}" '
                  f'tangentalDistortion1="{_n(p1)}" tangentalDistortion2="{_n(p2)}"/>',
                  "    </camera>"]
    parts += [extra, "  </cameras>", "</calibration>"]
    path.write_text("\n".join(parts) + "\n")
    return path


def write_xcp(path: Path, cams: list[KnownCamera]) -> Path:
    """A Vicon ``.xcp``: video cameras (SYSTEM="DV"), orientation quaternions (x y z w, from
    scipy), positions in mm, ``VICON_RADIAL2`` with k1 k2 k3; plus one marker camera."""
    parts = ['<?xml version="1.0" encoding="UTF-8"?>', '<Cameras VERSION="1.0">',
             '  <Camera DEVICEID="999" SYSTEM="MX" SENSOR_SIZE="2048 1088" PIXEL_ASPECT_RATIO="1"><KeyFrames>'
             '<KeyFrame FOCAL_LENGTH="1" PRINCIPAL_POINT="1 1" ORIENTATION="0 0 0 1" POSITION="0 0 0"/>'
             '</KeyFrames></Camera>']
    for c in cams:
        q = Rotation.from_matrix(c.R).as_quat()                 # x, y, z, w
        k1, k2, _, _, k3 = c.dist
        parts += [f'  <Camera DEVICEID="{c.name}" SYSTEM="DV" SENSOR_SIZE="{c.size[0]} {c.size[1]}" '
                  f'PIXEL_ASPECT_RATIO="{_n(c.K[0, 0] / c.K[1, 1])}">',
                  f'    <KeyFrames><KeyFrame FOCAL_LENGTH="{_n(c.K[0, 0])}" '
                  f'PRINCIPAL_POINT="{_n(c.K[0, 2])} {_n(c.K[1, 2])}" ORIENTATION="{" ".join(map(_n, q))}" '
                  f'POSITION="{" ".join(_n(v) for v in c.center * 1000)}" WORLD_ERROR="0.3" '
                  f'VICON_RADIAL2="ThreeParameter {_n(c.K[0, 2])} {_n(c.K[1, 2])} {_n(k1)} {_n(k2)} {_n(k3)}"/>'
                  "</KeyFrames>",
                  "  </Camera>"]
    path.write_text("\n".join(parts + ["</Cameras>"]) + "\n")
    return path


def _yml_matrix(key: str, m: np.ndarray) -> str:
    m = np.atleast_2d(m)
    return (f"{key}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d\n"
            f"   data: [ {', '.join(repr(float(v)) for v in m.reshape(-1))} ]\n")


def write_easymocap(folder: Path, cams: list[KnownCamera]) -> Path:
    """EasyMocap's ``intri.yml`` and ``extri.yml`` (OpenCV FileStorage YAML) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    names = "names:\n" + "".join(f'   - "{c.name}"\n' for c in cams)
    intri, extri = "%YAML:1.0\n---\n" + names, "%YAML:1.0\n---\n" + names
    for c in cams:
        intri += _yml_matrix(f"K_{c.name}", c.K) + _yml_matrix(f"dist_{c.name}", c.dist[None])
        intri += f"H_{c.name}: {c.size[1]}\nW_{c.name}: {c.size[0]}\n"
        extri += _yml_matrix(f"R_{c.name}", cv2.Rodrigues(c.R)[0]) + _yml_matrix(f"Rot_{c.name}", c.R)
        extri += _yml_matrix(f"T_{c.name}", c.t[:, None])
    (folder / "intri.yml").write_text(intri)
    (folder / "extri.yml").write_text(extri)
    return folder / "intri.yml"


#: OpenCap's board world -> z up (independent of the converter's constant: written out here).
_OPENCAP_A = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])


def write_opencap(folder: Path, cams: list[KnownCamera]) -> Path:
    """OpenCap's ``<folder>/CamN/cameraIntrinsicsExtrinsics.pickle``: numpy arrays, rotation in
    the board's world (y down the upright board), translation in mm."""
    for i, c in enumerate(cams):
        cam = folder / f"Cam{i}"
        cam.mkdir(parents=True, exist_ok=True)
        R_board = c.R @ _OPENCAP_A                                # x_cam = R (A^T X') with X' = A X
        data = {"intrinsicMat": c.K, "distortion": c.dist[None], "imageSize": np.array([[c.size[1]], [c.size[0]]]),
                "rotation": R_board, "translation": c.t[:, None] * 1000,
                "rotation_EulerAngles": cv2.Rodrigues(R_board)[0]}
        (cam / "cameraIntrinsicsExtrinsics.pickle").write_bytes(pickle.dumps(data, protocol=2))
    return folder / "Cam0" / "cameraIntrinsicsExtrinsics.pickle"


def _toml_list(values) -> str:
    return "[" + ", ".join(_toml_list(v) if isinstance(v, (list, np.ndarray)) else repr(float(v)) for v in values) + "]"


def write_anipose(path: Path, cams: list[KnownCamera], unit: float = 1000.0) -> Path:
    """aniposelib's ``calibration.toml`` (``[cam_N]`` tables), translations in metres * ``unit``."""
    text = ""
    for i, c in enumerate(cams):
        text += (f'[cam_{i}]\nname = "{c.name}"\nsize = [{c.size[0]}, {c.size[1]}]\nmatrix = {_toml_list(c.K)}\n'
                 f"distortions = {_toml_list(c.dist)}\nrotation = {_toml_list(cv2.Rodrigues(c.R)[0].reshape(3))}\n"
                 f"translation = {_toml_list(c.t * unit)}\n\n")
    path.write_text(text + "[metadata]\nadjusted = true\nerror = 0.5\n")
    return path


def write_caliscope(path: Path, cams: list[KnownCamera]) -> Path:
    """caliscope's ``config.toml``: ``[cam_<port>]`` with a 3 x 3 rotation, metres; plus an
    ignored camera and a camera without extrinsics (both left out)."""
    text = "fps_recording = 24\n\n"
    for port, c in enumerate(cams):
        text += (f"[cam_{port}]\nport = {port}\nsize = [{c.size[0]}, {c.size[1]}]\nrotation_count = 0\nerror = 0.2\n"
                 f"matrix = {_toml_list(c.K)}\ndistortions = {_toml_list(c.dist)}\n"
                 f"translation = {_toml_list(c.t)}\nrotation = {_toml_list(c.R)}\nignore = false\n\n")
    c = cams[0]
    text += (f"[cam_7]\nport = 7\nsize = [640, 480]\nrotation_count = 0\nerror = 0.2\nmatrix = {_toml_list(c.K)}\n"
             f"distortions = {_toml_list(c.dist)}\ntranslation = {_toml_list(c.t)}\nrotation = {_toml_list(c.R)}\n"
             "ignore = true\n\n[cam_8]\nport = 8\nsize = [640, 480]\nrotation_count = 0\nignore = false\n\n"
             '[charuco]\ncolumns = 4\nrows = 5\nunits = "inch"\n')
    path.write_text(text)
    return path


def write_biocv(folder: Path, cams: list[KnownCamera]) -> Path:
    """bioCV's per-camera text files ``<name>.calib``: size, K, [R | t] in mm, distortion."""
    folder.mkdir(parents=True, exist_ok=True)
    for c in cams:
        rows = [[c.size[0]], [c.size[1]], *c.K.tolist(), [], *np.hstack([c.R, c.t[:, None] * 1000]).tolist(), [],
                c.dist.tolist()]
        (folder / f"{c.name}.calib").write_text("\n".join(" ".join(repr(float(v)) for v in r) for r in rows) + "\n")
    return folder / f"{cams[0].name}.calib"
