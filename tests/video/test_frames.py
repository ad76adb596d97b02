"""Frame sampling, blur rejection, the frame <-> timestamp index, people-based scale and
camera imports (RealEstate10K / MannequinChallenge files, COLMAP models)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from mvm.errors import InputError
from mvm.sim.people import STANDING
from mvm.video.frames import FrameOptions, extract_frames, read_frame_index, sample_indices, sharp_mask
from mvm.video.metric_scale import people_scale


def test_sample_indices_rate_and_count():
    assert sample_indices(100, 30.0, 10.0, None).tolist() == list(range(0, 100, 3))
    picked = sample_indices(100, 30.0, None, 5)
    assert picked.tolist() == [0, 25, 50, 74, 99]
    with pytest.raises(ValueError, match="rate"):
        sample_indices(10, 30.0, -1.0, None)


def test_sharp_mask():
    assert sharp_mask(np.array([100, 90, 10, 110.0]), 0.5).tolist() == [True, True, False, True]
    assert sharp_mask(np.array([1.0, 100.0]), 0.0).all()


@pytest.fixture
def video(tmp_path):
    """30 frames at 10 fps of a moving texture; frame 12 is blurred."""
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 255, (240, 400, 3), dtype=np.uint8)
    path = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (320, 180))
    for k in range(30):
        frame = np.ascontiguousarray(texture[20:200, k:k + 320])
        if k == 12:
            frame = cv2.GaussianBlur(frame, (0, 0), 6)
        writer.write(frame)
    writer.release()
    return path


def test_extract_frames_skips_blurred_and_keeps_timestamps(video, tmp_path):
    scene = tmp_path / "scene"
    index = extract_frames(video, scene, FrameOptions(rate=5.0, width=160))
    assert 12 in index.skipped
    assert index.numbers.tolist() == [k for k in range(0, 30, 2) if k != 12]
    assert np.allclose(index.timestamps, index.numbers / 10.0)
    assert index.size == (160, 90)
    assert cv2.imread(str(scene / "frames" / "frame_00004.jpg")).shape == (90, 160, 3)
    again = read_frame_index(scene)
    assert again.names == index.names and np.allclose(again.timestamps, index.timestamps)
    # done work is kept, work with other options or forced is redone
    stamp = (scene / "frames.json").stat().st_mtime_ns
    assert extract_frames(video, scene, FrameOptions(rate=5.0, width=160)).why is None
    assert (scene / "frames.json").stat().st_mtime_ns == stamp
    redone = extract_frames(video, scene, FrameOptions(rate=1.0, width=160))
    assert redone.why == "setting rate changed since the frame extraction (5.0 -> 1.0)"
    assert len(redone.names) == 3 and sorted(p.name for p in (scene / "frames").iterdir()) == list(redone.names)
    assert len(extract_frames(video, scene, FrameOptions(rate=1.0, blur_ratio=0), force=True).names) == 3


def test_streaming_writes_what_decoding_everything_in_memory_gives(video, tmp_path):
    """The frames written one at a time are those of the whole clip decoded into memory, resized
    and encoded the same way; blurred ones are not left on disk."""
    capture = cv2.VideoCapture(str(video))
    decoded = []
    while True:
        ok, image = capture.read()
        if not ok:
            break
        decoded.append(cv2.resize(image, (200, 112), interpolation=cv2.INTER_AREA))
    capture.release()
    scene = tmp_path / "scene"
    index = extract_frames(video, scene, FrameOptions(rate=5.0, width=200))
    assert sorted(p.name for p in (scene / "frames").iterdir()) == sorted(index.names)
    for name, k in zip(index.names, index.numbers):
        ok, data = cv2.imencode(".jpg", decoded[k], [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert (scene / "frames" / name).read_bytes() == data.tobytes()
    sampled = np.arange(0, 30, 2)
    from mvm.video.frames import sharpness

    want_sharp = np.array([sharpness(decoded[k]) for k in sampled])
    keep = sharp_mask(want_sharp, 0.35)
    assert index.numbers.tolist() == sampled[keep].tolist()
    assert np.allclose(index.sharpness, want_sharp[keep])


def test_bad_video_is_one_line(tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video")
    with pytest.raises(InputError) as info:
        extract_frames(bad, tmp_path / "scene")
    assert str(bad) in str(info.value)


def test_people_scale_recovers_units_and_ignores_an_outlier():
    rng = np.random.default_rng(0)
    people = STANDING[None] * rng.uniform(0.95, 1.05, (6, 1, 1))
    truth, _ = people_scale(people)
    model = people / 3.7                      # SfM units: 3.7 m per unit
    model[0] *= 2.5                            # one badly reconstructed person
    model[1, 7] = np.nan                       # a missing elbow
    s, bones = people_scale(model)
    assert bones == 12
    assert abs(s / (3.7 * truth) - 1) < 0.03
    with pytest.raises(ValueError, match="shape"):
        people_scale(np.zeros((2, 17, 2)))
    assert np.isnan(people_scale(np.full((1, 17, 3), np.nan))[0])


def test_import_trajectory_matches_frames_by_timestamp(tmp_path):
    from mvm.io.colmap import read_colmap
    from mvm.io.files import atomic_write_json
    from mvm.video.frames import FrameIndex
    from mvm.video.sfm import import_trajectory

    scene = tmp_path / "scene"
    numbers = np.arange(0, 10)
    index = FrameIndex("v.mp4", 30.0, (640, 360), tuple(f"frame_{k:05d}.jpg" for k in numbers), numbers,
                       numbers / 30.0, np.ones(10))
    atomic_write_json(scene / "frames.json", index.to_json())
    lines = ["https://www.youtube.com/watch?v=example"]
    rng = np.random.default_rng(1)
    truth = {}
    for k in range(8):  # frames 8, 9 have no camera line
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
        t = rng.normal(0, 1, 3)
        truth[k] = (R, t)
        Rt = np.concatenate([R, t[:, None]], axis=1).reshape(-1)
        stamp = int(round(k / 30.0 * 1e6)) + 3000          # 3 ms off the frame time
        lines.append(" ".join([str(stamp), "0.5", "0.888889", "0.5", "0.5", "0", "0"] + [f"{v:.9f}" for v in Rt]))
    path = tmp_path / "cams.txt"
    path.write_text("\n".join(lines) + "\n")
    report = import_trajectory(path, scene)
    assert report.unregistered == ["frame_00008.jpg", "frame_00009.jpg"]
    model = read_colmap(scene / "sparse")
    assert len(model.cameras) == 8
    k = model.cameras.names.index("frame_00005.jpg")
    assert np.allclose(model.cameras.R[k], truth[5][0], atol=1e-6)
    assert np.allclose(model.cameras.t[k], truth[5][1], atol=1e-6)
    assert np.allclose(model.cameras.K[k][[0, 1, 0, 1], [0, 1, 2, 2]], [320, 320, 320, 180], atol=1e-3)
    bad = tmp_path / "bad.txt"
    bad.write_text(lines[0] + "\n1 2 3\n")
    with pytest.raises(InputError) as info:
        import_trajectory(bad, scene)
    assert str(bad) in str(info.value) and "line 2" in str(info.value)
