"""parse_json reads what json.loads reads, the same way, whichever parser does the work."""
import json
import math

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.checks import parse_json

SPECIAL = ['{"a": 1, "a": 2}', '[1e400, -1e400]', '{"x": NaN, "y": Infinity, "z": -Infinity}',
           '[18446744073709551616, 9223372036854775808, -9223372036854775809]', '"\\ud83d\\ude00 é"',
           '[0.1234567890123456789, 1E-7, -0.0, 5e-324]', "[" * 300 + "]" * 300, ' {"people": [ ]} ', "123"]


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


@pytest.mark.parametrize("text", SPECIAL)
def test_special_texts_parse_as_json_loads_does(text):
    assert _same(parse_json(text, "f.json"), json.loads(text))


def test_random_pose_files_parse_as_json_loads_does():
    rng = np.random.default_rng(0)
    for _ in range(200):
        people = [{"person_id": [int(rng.integers(-1, 5))],
                   "pose_keypoints_2d": [float(v) if rng.random() < 0.8 else int(v)
                                         for v in rng.normal(500, 300, 75) * 10.0 ** rng.integers(-8, 8)]}
                  for _ in range(rng.integers(0, 5))]
        text = json.dumps({"version": 1.3, "people": people}, indent=int(rng.integers(0, 3)) or None)
        assert _same(parse_json(text, "f.json"), json.loads(text))


@pytest.mark.parametrize("text,problem", [("{", "not valid JSON: Expecting property name"),
                                          ("[1, 2", "not valid JSON: Expecting ',' delimiter"),
                                          ("[" * 100_000, "not valid JSON: nested too deeply")])
def test_bad_json_is_one_line_naming_the_file(text, problem):
    with pytest.raises(InputError) as info:
        parse_json(text, "pose/cam1/0001.json")
    assert str(info.value).startswith(f"pose/cam1/0001.json: {problem}")


def test_openpose_files_in_bulk_read_as_one_by_one(tmp_path):
    """Plain files of two layouts, a file with no people and one that needs the person-by-person
    reading give what each file read alone gives; a non-finite number is named in its file."""
    from mvm.io.openpose import read_openpose_frame, read_openpose_frames

    rng = np.random.default_rng(1)
    texts = [{"people": [{"pose_keypoints_2d": rng.uniform(0, 900, 75).tolist()} for _ in range(3)]},
             {"people": []},
             {"people": [{"pose_keypoints_2d": rng.uniform(0, 900, 54).tolist()}]},
             {"people": [{"pose_keypoints_2d": [int(v) for v in rng.integers(0, 900, 75)], "extra": 1}]},
             {"people": [{"pose_keypoints_2d": rng.uniform(0, 900, 75).tolist()}, {"face": []}]}]
    paths = []
    for i, data in enumerate(texts[:4]):
        paths.append(tmp_path / f"{i:04d}_keypoints.json")
        paths[-1].write_text(json.dumps(data))
    together = read_openpose_frames(paths, root=tmp_path)
    for path, kp in zip(paths, together):
        assert np.array_equal(kp, read_openpose_frame(path, root=tmp_path))
    bad = tmp_path / "0004_keypoints.json"
    bad.write_text(json.dumps(texts[4]))
    with pytest.raises(InputError, match=r"0004_keypoints.json: people\[1\].pose_keypoints_2d: missing"):
        read_openpose_frames(paths + [bad], root=tmp_path)
    texts[0]["people"][1]["pose_keypoints_2d"][4] = 1e400
    paths[0].write_text(json.dumps(texts[0]).replace("Infinity", "1e400"))
    with pytest.raises(InputError, match=r"0000_keypoints.json: people\[1\].pose_keypoints_2d"):
        read_openpose_frames(paths, root=tmp_path)
