"""Rebuild the corpus of malformed input files in this folder.

Every case starts from a valid file made by the project's writers (or in the format's
published layout) and breaks one thing. ``expected.toml`` (written by hand, not by this
script) holds the exact error line each case must produce; ``tests/io/test_bad_inputs.py``
checks them. Run from the repository root: ``python tests/data/bad/make_corpus.py``.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import struct
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from helpers import random_cameras, standing_poses  # noqa: E402


def _cameras(V=3):
    return random_cameras(np.random.default_rng(0), V)


def _keypoints(cams):
    X = standing_poses(1)[0]
    cam = np.einsum("vij,nj->vni", cams.R, X) + cams.t[:, None]
    xy = cam[..., :2] / cam[..., 2:] * 1000.0 + cams.K[:, None, :2, 2]
    return np.round(np.concatenate([xy, np.full((len(cams), 17, 1), 0.9)], axis=2), 2)


def _write(rel: str, data) -> None:
    path = HERE / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data if isinstance(data, bytes) else data.encode())


def _coco_doc():
    from mvm.io.coco import coco_keypoints_document

    cams = _cameras()
    return coco_keypoints_document(cams.names, cams.size, np.arange(3), _keypoints(cams), np.full(3, 0.9))


def coco() -> None:
    def case(name, mutate):
        doc = _coco_doc()
        mutate(doc)
        _write(f"coco/{name}.json", json.dumps(doc))

    _write("coco/not_json.json", '{"images": [')
    _write("coco/bad_utf8.json", b'{"images": [], "annotations": [], "info": "\xff"}')
    _write("coco/nested_too_deep.json", "[" * 100000 + "]" * 100000)
    _write("coco/huge_integer_literal.json", '{"images": [{"id": ' + "1" * 5000 + "}]}")
    case("images_not_list", lambda d: d.update(images={"id": 1}))
    case("duplicate_image_id", lambda d: d["images"][1].update(id=1))
    case("duplicate_file_name", lambda d: d["images"][2].update(file_name="f0000.jpg"))
    case("file_name_absolute", lambda d: d["images"][0].update(file_name="/etc/passwd"))
    case("file_name_dotdot", lambda d: d["images"][1].update(file_name="frames/../../../secret.jpg"))
    case("file_name_windows_absolute", lambda d: d["images"][0].update(file_name="C:\\frames\\f0000.jpg"))
    case("width_zero", lambda d: d["images"][0].update(width=0))
    case("height_string", lambda d: d["images"][2].update(height="720"))
    case("image_id_out_of_range", lambda d: d["images"][0].update(id=2 ** 64))
    case("keypoints_short", lambda d: d["annotations"][1].update(keypoints=d["annotations"][1]["keypoints"][:34]))
    case("keypoints_not_list", lambda d: d["annotations"][0].update(keypoints="1 2 3"))
    case("keypoint_bool", lambda d: d["annotations"][0]["keypoints"].__setitem__(5, True))
    case("keypoint_huge", lambda d: d["annotations"][2]["keypoints"].__setitem__(0, 10 ** 400))
    case("negative_confidence", lambda d: d["annotations"][0]["keypoints"].__setitem__(2, -0.5))
    case("score_negative", lambda d: d["annotations"][0].update(score=-1))
    case("unknown_image_id", lambda d: d["annotations"][2].update(image_id=9))
    case("duplicate_annotation_id", lambda d: d["annotations"][2].update(id=1))
    case("appearance_on_some", lambda d: d["annotations"][0].update(appearance=[0.1, 0.2]))
    case("category_list", lambda d: d["annotations"][0].update(category_id=[1]))
    doc = _coco_doc()                     # NaN is not JSON, but Python's json module writes it
    doc["annotations"][2]["keypoints"][4] = float("nan")
    _write("coco/keypoint_nan.json", json.dumps(doc))


def openpose() -> None:
    cams = _cameras()
    kp = _keypoints(cams)[0].reshape(-1).tolist()

    def case(name, people):
        _write(f"openpose/{name}_000001_keypoints.json", json.dumps({"version": 1.3, "people": people}))

    case("wrong_length", [{"pose_keypoints_2d": kp[:48]}])
    case("not_a_list", [{"pose_keypoints_2d": {"x": 1}}])
    case("missing_keypoints", [{"person_id": [-1]}])
    case("infinite", [{"pose_keypoints_2d": kp[:3] + [float("inf")] + kp[4:]}])
    _write("openpose/people_missing_000001_keypoints.json", json.dumps({"version": 1.3}))


def openpifpaf() -> None:
    kp = _keypoints(_cameras())[0].reshape(-1).tolist()
    _write("openpifpaf/not_a_list.predictions.json", json.dumps({"keypoints": kp}))
    _write("openpifpaf/keypoints_short.predictions.json", json.dumps([{"keypoints": kp[:3], "score": 0.5}]))
    _write("openpifpaf/score_string.predictions.json", json.dumps([{"keypoints": kp, "score": "high"}]))
    _write("openpifpaf/score_negative.predictions.json", json.dumps([{"keypoints": kp, "score": -0.1}]))


def calib_toml() -> None:
    from mvm.io.calib_toml import RigCalibration, calib_toml_text

    cams = _cameras(2)
    text = calib_toml_text(RigCalibration(dataclasses.replace(cams, distortion=(np.zeros(4), np.zeros(4)))))
    first_t = text.split("translation = ")[1].split("\n")[0]
    first_m = text.split("matrix = ")[1].split("\n")[0]
    _write("calib_toml/not_toml.toml", "[cam_1\nname = 1\n")
    _write("calib_toml/bad_utf8.toml", text.encode()[:40] + b"\xff\xfe" + text.encode()[40:])
    _write("calib_toml/translation_short.toml", text.replace(first_t, "[ 0.1, 0.2,]", 1))
    _write("calib_toml/focal_zero.toml",
           text.replace(first_m, "[ [ 0.0, 0.0, 640.0,], [ 0.0, 1000.0, 360.0,], [ 0.0, 0.0, 1.0,],]", 1))
    _write("calib_toml/size_negative.toml", text.replace("size = [ 1280.0, 720.0,]", "size = [ -1280.0, 720.0,]", 1))
    _write("calib_toml/fisheye_string.toml", text.replace("fisheye = false", 'fisheye = "false"', 1))
    _write("calib_toml/matrix_strings.toml",
           text.replace(first_m, '[ [ "1000", 0.0, 640.0,], [ 0.0, 1000.0, 360.0,], [ 0.0, 0.0, 1.0,],]', 1))
    _write("calib_toml/no_camera.toml", "[metadata]\nadjusted = false\n")
    _write("calib_toml/camera_without_matrix.toml", text.replace(f"matrix = {first_m}\n", "", 1))


def trajectory() -> None:
    cams = _cameras()
    lines = ["https://www.youtube.com/watch?v=abcdefghijk"]
    for f in range(3):
        Rt = np.concatenate([cams.R[f], cams.t[f][:, None]], axis=1)
        lines.append(" ".join(f"{v:.9g}" for v in [1000 * (f + 1), 0.8, 1.4, 0.5, 0.5, 0, 0] + Rt.reshape(-1).tolist()))

    def case(name, k, line):
        out = list(lines)
        if line is None:
            del out[k:]
        else:
            out[k] = line
        _write(f"trajectory/{name}.txt", "\n".join(out) + "\n")

    case("missing_column", 2, lines[2].rsplit(" ", 1)[0])
    case("nan", 3, lines[3].replace(" 0.8 ", " nan ", 1))
    case("not_a_rotation", 1, lines[1].replace(" 0 0 ", " 0 0 2 ", 1).rsplit(" ", 1)[0])
    case("timestamps_not_increasing", 3, lines[3].replace("3000 ", "1000 ", 1))
    case("one_frame", 2, None)
    case("focal_negative", 2, lines[2].replace(" 0.8 ", " -0.8 ", 1))
    case("no_url", 0, "")


def panoptic_calib() -> None:
    cams = _cameras()
    cameras = [{"name": f"00_{v:02d}", "type": "hd", "resolution": [1920, 1080], "K": cams.K[v].tolist(),
                "distCoef": [0.0] * 5, "R": cams.R[v].tolist(), "t": (100 * cams.t[v])[:, None].tolist()}
               for v in range(3)]

    def case(name, mutate):
        doc = {"calibCameras": 1, "cameras": json.loads(json.dumps(cameras))}
        mutate(doc)
        _write(f"panoptic_calib/{name}.json", json.dumps(doc))

    case("camera_not_object", lambda d: d["cameras"].__setitem__(1, "00_01"))
    case("missing_K", lambda d: d["cameras"][0].pop("K"))
    case("R_not_rotation", lambda d: d["cameras"][2]["R"][0].__setitem__(0, 5.0))
    case("resolution_zero", lambda d: d["cameras"][1].update(resolution=[0, 1080]))
    case("no_hd_camera", lambda d: [c.update(type="vga") for c in d["cameras"]])


def trc() -> None:
    from mvm.io.trc import trc_text

    text = trc_text(standing_poses(3)[:, :4], ["nose", "l_eye", "r_eye", "l_ear"], 30.0, name="p.trc")
    lines = text.split("\n")
    _write("trc/no_header.trc", "\n".join(lines[1:]))
    _write("trc/frame_infinite.trc", "\n".join(lines[:7] + ["inf" + lines[7][1:]] + lines[8:]))
    _write("trc/num_markers_mismatch.trc", text.replace("\t3\t4\tm\t", "\t3\t5\tm\t", 1))
    _write("trc/extra_columns.trc", "\n".join(lines[:6] + [lines[6] + "\t1.0\t2.0"] + lines[7:]))
    _write("trc/rate_zero.trc", text.replace("30\t30\t3", "0\t30\t3", 1))
    fields = lines[7].split("\t")
    fields[3] = "-inf"
    _write("trc/coordinate_infinite.trc", "\n".join(lines[:7] + ["\t".join(fields)] + lines[8:]))


def config() -> None:
    _write("config/tau_string.toml", 'tau = "high"\n')
    _write("config/gamma_bool.toml", "gamma = true\n")
    _write("config/min_views_float.toml", "min_views = 2.5\n")
    _write("config/reconstruct_not_table.toml", "reconstruct = 3\n")
    _write("config/bad_utf8.toml", b"tau = 0.2\n# \xff\xfe\n")
    _write("config/not_toml.toml", "tau = \n")
    _write("config/nan.toml", "prior_weight = nan\n")
    _write("config/negative.toml", "ransac_threshold = -2.0\n")


def _colmap_bin(name: str, edit) -> None:
    from mvm.io.colmap import write_colmap

    cams = _cameras()
    folder = HERE / "colmap_bin" / name
    shutil.rmtree(folder, ignore_errors=True)
    write_colmap(folder, cams, binary=True, points3d=standing_poses(1)[0][:4])
    files = {p.name: bytearray(p.read_bytes()) for p in folder.iterdir()}
    edit(files)
    for file, data in files.items():
        (folder / file).write_bytes(bytes(data))


def colmap_bin() -> None:
    def pack(file, offset, fmt, *values):
        return lambda f: struct.pack_into("<" + fmt, f[file], offset, *values)

    def truncated(f):
        f["images.bin"] = f["images.bin"][:158]           # inside the second image's name
        struct.pack_into("<Q", f["images.bin"], 0, 2)

    _colmap_bin("truncated_in_name", truncated)
    _colmap_bin("count_too_large", pack("points3D.bin", 0, "Q", 2 ** 32))
    _colmap_bin("unknown_camera_model", pack("cameras.bin", 12, "i", 99))
    _colmap_bin("width_zero", pack("cameras.bin", 16, "Q", 0))
    _colmap_bin("focal_nan", pack("cameras.bin", 32, "d", float("nan")))
    _colmap_bin("zero_quaternion", pack("images.bin", 12, "4d", 0.0, 0.0, 0.0, 0.0))
    _colmap_bin("frame_zero_quaternion", pack("frames.bin", 16, "4d", 0.0, 0.0, 0.0, 0.0))
    _colmap_bin("duplicate_image_id", pack("images.bin", 90, "I", 1))
    _colmap_bin("unknown_camera_id", pack("images.bin", 68, "I", 5))
    _colmap_bin("trailing_bytes", lambda f: f["points3D.bin"].extend(b"\0" * 5))
    _colmap_bin("image_name_absolute",
                lambda f: f.update({"images.bin": f["images.bin"].replace(b"f0000.jpg", b"/etc/pass")}))
    _colmap_bin("image_name_not_utf8",
                lambda f: f.update({"images.bin": f["images.bin"].replace(b"f0001.jpg", b"f\xff01.jpg")}))
    _colmap_bin("missing_images", lambda f: f.pop("images.bin"))
    (HERE / "colmap_bin" / "missing_images" / "images.bin").unlink()


def _colmap_txt(name: str, file: str, old: str, new: str) -> None:
    from mvm.io.colmap import write_colmap

    folder = HERE / "colmap_txt" / name
    shutil.rmtree(folder, ignore_errors=True)
    write_colmap(folder, _cameras(), binary=False, points3d=standing_poses(1)[0][:4])
    text = (folder / file).read_text()
    assert old in text, (name, old)
    (folder / file).write_text(text.replace(old, new, 1))


def colmap_txt() -> None:
    _colmap_txt("extra_camera_parameter", "cameras.txt", "640 360\n", "640 360 0.1\n")
    _colmap_txt("unknown_camera_model", "cameras.txt", " PINHOLE ", " PINHOLE_2 ")
    _colmap_txt("height_negative", "cameras.txt", " 720 ", " -720 ")
    _colmap_txt("image_line_short", "images.txt", " 1 f0001.jpg", " f0001.jpg")
    _colmap_txt("image_name_dotdot", "images.txt", " f0002.jpg", " ../../f0002.jpg")
    _colmap_txt("pose_nan", "images.txt", "\n2 0.62472287703663265 ", "\n2 nan ")
    _colmap_txt("frames_huge_data_count", "frames.txt", " 1 CAMERA 1 1\n", " 4000000000 CAMERA 1 1\n")
    _colmap_txt("points2d_not_triples", "images.txt", "f0000.jpg\n\n", "f0000.jpg\n1.0 2.0\n")
    _colmap_txt("point_not_number", "points3D.txt", "\n2 ", "\n2 x")
    _colmap_txt("track_index_out_of_range", "points3D.txt", " 0 0 0 -1 \n", " 0 0 0 -1 2 7\n")
    _colmap_txt("track_unknown_image", "points3D.txt", " 0 0 0 -1 \n", " 0 0 0 -1 9 0\n")
    _colmap_txt("frames_missing", "frames.txt", "", "")
    (HERE / "colmap_txt" / "frames_missing" / "frames.txt").unlink()


def scene() -> None:
    from mvm.core.scene import Poses2D
    from mvm.io.scene_dir import write_scene

    cams = _cameras()
    kp = _keypoints(cams)
    poses = Poses2D(kp, np.arange(3), np.arange(1, 4), np.full(3, 0.9), None)

    def case(name, coco_name=None, colmap_name=None):
        folder = HERE / "scene" / name
        shutil.rmtree(folder, ignore_errors=True)
        write_scene(folder, cams, poses, binary=False)
        if coco_name:
            doc = json.loads((folder / "poses2d.json").read_text())
            doc["images"][0]["file_name"] = coco_name
            (folder / "poses2d.json").write_text(json.dumps(doc))
        if colmap_name:
            images = folder / "sparse" / "images.txt"
            images.write_text(images.read_text().replace(" f0000.jpg", " " + colmap_name))

    case("file_name_dotdot", "../../../etc/passwd")
    case("file_name_absolute", "/etc/passwd")
    case("colmap_name_dotdot", colmap_name="../outside.jpg")
    case("both_names_dotdot", "../f0000.jpg", "../f0000.jpg")
    case("not_in_model", "frame_9.jpg")


def poses3d() -> None:
    from mvm.core.scene import Persons3D, Poses2D
    from mvm.io.scene_dir import poses3d_document

    X = standing_poses(2)
    persons = Persons3D(X, np.full((2, 17), 0.8), [np.array([0, 1]), np.array([2])], np.full((2, 17), 3),
                        np.zeros((2, 17), int), np.array([1.5, 2.0]))
    poses = Poses2D(np.zeros((3, 17, 3)), np.arange(3), np.arange(1, 4), np.ones(3), None)

    def case(name, mutate):
        doc = poses3d_document(persons, poses, {"persons": 2})
        mutate(doc)
        _write(f"poses3d/{name}.json", json.dumps(doc))

    case("person_not_object", lambda d: d["persons"].__setitem__(1, [1, 2, 3]))
    case("coordinate_infinite", lambda d: d["persons"][0]["keypoints3d"][5].__setitem__(1, float("inf")))
    case("views_short", lambda d: d["persons"][1].update(views_per_joint=[3] * 16))
    case("member_string", lambda d: d["persons"][0]["members"].__setitem__(0, "1"))
    case("wrong_format", lambda d: d.update(format="mvm.poses3d/0"))
    case("coordinate_huge", lambda d: d["persons"][1]["keypoints3d"][2].__setitem__(0, 1e308))
    case("metrics_nan", lambda d: d["metrics"].update(E_R_px=float("nan")))


def main() -> None:
    for build in (poses3d, coco, openpose, openpifpaf, calib_toml, trajectory, panoptic_calib, trc, config,
                  colmap_bin, colmap_txt, scene):
        build()


if __name__ == "__main__":
    main()
