"""3DPW: the reader of the published pickle layout and the paper's protocol (Table 3)."""
import pickle

import numpy as np
import pytest

from mvm.core.keypoints import INDEX
from mvm.errors import InputError
from mvm.metrics.network import COMMON14_NAMES, threedpw_pa_mpjpe
from mvm.net import evaluate as net_evaluate
from mvm.net.threedpw import COCO18_TO_COMMON14, SMPL_TO_COMMON14, read_3dpw, read_sequence

K = np.array([[1000.0, 0, 540], [0, 1000.0, 960], [0, 0, 1]])


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _clip(rng, n_frames=4, n_people=2):
    """Ground truth of a clip: SMPL joints in the world, cameras, and COCO-18 2D joints."""
    X = rng.normal(scale=0.3, size=(n_people, n_frames, 24, 3)) + [0, 0, 0]
    X[..., 12, :] = 0.5 * (X[..., 16, :] + X[..., 17, :])          # the neck at mid-shoulders, as COCO's
    cam = np.tile(np.eye(4), (n_frames, 1, 1))
    for f in range(n_frames):
        cam[f, :3, :3] = _rotation(rng)
        cam[f, :3, 3] = [0.2 * f, 0.1, 5.0]
    Xc = np.einsum("fij,pfkj->pfki", cam[:, :3, :3], X) + cam[None, :, None, :3, 3]
    uv = Xc[..., :2] / Xc[..., 2:] * 1000.0 + [540, 960]
    p2d = np.zeros((n_people, n_frames, 3, 18))
    for smpl, coco18 in zip(SMPL_TO_COMMON14, COCO18_TO_COMMON14):
        p2d[:, :, :2, coco18] = uv[:, :, smpl]
        p2d[:, :, 2, coco18] = 0.9
    return X, cam, p2d, Xc


def _write(root, name, X, cam, p2d, valid):
    folder = root / "sequenceFiles" / "test"
    folder.mkdir(parents=True, exist_ok=True)
    n_people, n_frames = X.shape[:2]
    doc = {"sequence": name, "img_frame_ids": np.arange(n_frames) * 3 + 1, "cam_poses": cam, "cam_intrinsics": K,
           "jointPositions": [X[p].reshape(n_frames, 72) for p in range(n_people)],
           "poses2d": [p2d[p] for p in range(n_people)], "campose_valid": [valid[p] for p in range(n_people)],
           "betas": [np.zeros(10)] * n_people, "genders": ["m"] * n_people}
    path = folder / f"{name}.pkl"
    path.write_bytes(pickle.dumps(doc, protocol=2))
    return path


def test_reader_takes_the_14_joints_into_the_camera_frame(tmp_path):
    rng = np.random.default_rng(0)
    X, cam, p2d, Xc = _clip(rng)
    valid = np.ones((2, 4), bool)
    valid[1, 2] = False                                          # this camera pose is not aligned for person 1
    p2d[0, 1, 2, list(COCO18_TO_COMMON14)[:8]] = 0.0               # 8 joints not visible: 6 left
    path = _write(tmp_path, "downtown_walk_00", X, cam, p2d, valid)
    data = read_sequence(path)
    assert len(data) == 7 and list(data.track) == [0, 0, 0, 0, 1, 1, 1] and list(data.frame) == [1, 4, 7, 10, 1, 4, 10]
    assert data.images[1] == tmp_path / "imageFiles" / "downtown_walk_00" / "image_00004.jpg"
    np.testing.assert_allclose(data.joints3d[5], Xc[1, 1, list(SMPL_TO_COMMON14)])
    assert data.visible[1].sum() == 6 and data.visible[0].all()
    assert COMMON14_NAMES[0] == "left_shoulder" and SMPL_TO_COMMON14[0] == 16 and COCO18_TO_COMMON14[0] == 5
    # the same 2D joints as the projection of the 3D ones
    uv = data.joints3d[..., :2] / data.joints3d[..., 2:] * 1000.0 + [540, 960]
    np.testing.assert_allclose(data.joints2d[0, :, :2], uv[0], atol=1e-9)
    both = read_3dpw(tmp_path, "test")
    assert len(both) == 7 and set(both.clip) == {"downtown_walk_00"}
    with pytest.raises(InputError, match="no .pkl"):
        read_3dpw(tmp_path, "validation")
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(pickle.dumps({"sequence": "x"}))
    with pytest.raises(InputError, match="img_frame_ids"):
        read_sequence(bad)


def _offset_orthogonal(G, size, rng):
    """Offsets ``(14, 3)`` with zero mean and ``Eᵀ G = 0`` (G centred): the best similarity is the identity."""
    basis = np.column_stack([np.ones(len(G)), G - G.mean(0)])
    E = rng.normal(size=G.shape)
    E -= basis @ np.linalg.lstsq(basis, E, rcond=None)[0]
    return size * E / np.linalg.norm(E, axis=1).mean()


def test_protocol_identity_similarity_and_known_offset(tmp_path):
    rng = np.random.default_rng(1)
    X, cam, p2d, _ = _clip(rng, n_frames=3, n_people=2)
    data = read_sequence(_write(tmp_path, "clip_a", X, cam, p2d, np.ones((2, 3), bool)))
    gt, vis = data.joints3d, data.visible
    error, per_track = threedpw_pa_mpjpe(gt.copy(), gt, vis, data.clip, data.track)
    assert error == pytest.approx(0.0, abs=1e-9) and len(per_track) == 2
    # a rotation, a scale and a translation per pose: nothing left after alignment
    moved = np.stack([2.5 * g @ _rotation(rng).T + rng.normal(size=3) for g in gt])
    assert threedpw_pa_mpjpe(moved, gt, vis, data.clip, data.track)[0] == pytest.approx(0.0, abs=1e-9)
    # offsets the alignment cannot absorb: 10 mm on person 0, 30 mm on person 1 (per joint, on average);
    # person 0's three frames and person 1's three frames count once each
    offsets = [_offset_orthogonal(g, 0.010 if t == 0 else 0.030, rng) for g, t in zip(gt, data.track)]
    error, per_track = threedpw_pa_mpjpe(gt + np.array(offsets), gt, vis, data.clip, data.track)
    assert per_track[("clip_a", 0)] == pytest.approx(0.010, rel=0.01)
    assert per_track[("clip_a", 1)] == pytest.approx(0.030, rel=0.01)
    assert error == pytest.approx(0.020, rel=0.01)
    # a subject with fewer than 7 visible joints is ignored, whatever its error
    vis2 = vis.copy()
    vis2[0, 6:] = False                                          # 6 visible joints
    wrong = gt + np.array(offsets)
    wrong[0] += rng.normal(scale=1.0, size=(14, 3))
    error, per_track = threedpw_pa_mpjpe(wrong, gt, vis2, data.clip, data.track)
    assert per_track[("clip_a", 0)] == pytest.approx(0.010, rel=0.01)


def test_evaluate_3dpw_matches_detections_to_people(tmp_path, monkeypatch):
    """The evaluation loop on the truth fed back as detections (with a spurious one): 0 mm."""
    rng = np.random.default_rng(2)
    X, cam, p2d, _ = _clip(rng, n_frames=2, n_people=2)
    data = read_sequence(_write(tmp_path, "clip_b", X, cam, p2d, np.ones((2, 2), bool)))
    limbs = [INDEX[n] for n in COMMON14_NAMES[:12]]

    def truth_as_detections(model, image, K_, input_size, decoder):
        rows = [i for i, p in enumerate(data.images) if p == image]
        kp2 = np.zeros((len(rows) + 1, 17, 3))
        kp3 = np.full((len(rows) + 1, 17, 3), np.nan)
        for k, i in enumerate(rows[::-1]):                         # detections in another order than the truth
            kp2[k, limbs], kp3[k, limbs] = data.joints2d[i, :12], data.joints3d[i, :12]
            kp2[k, INDEX["nose"]], kp3[k, INDEX["nose"]] = data.joints2d[i, 13], data.joints3d[i, 13]
        kp2[-1, :, :2], kp2[-1, :, 2] = 5.0, 0.9                    # a detection far from everyone
        return kp2, kp3

    class Model:
        training = False

        def eval(self):
            return self

        def train(self, mode):
            return self

    monkeypatch.setattr(net_evaluate, "predict_3d", truth_as_detections)
    monkeypatch.setattr(net_evaluate, "load_image", lambda path: path)
    result = net_evaluate.evaluate_3dpw(Model(), data)
    assert result["PA_MPJPE_mm"] == pytest.approx(0.0, abs=1e-6)
    assert (result["tracks"], result["poses"], result["missed"], result["images"]) == (2, 4, 0, 2)


# --- hostile files ------------------------------------------------------------------------------

class _Runs:
    """Unpickled as a call of ``os.system``: what a hostile data file would run."""

    def __init__(self, command):
        self.command = command

    def __reduce__(self):
        import os

        return os.system, (self.command,)


def _valid_doc(rng, n_frames=3):
    X, cam, p2d, _ = _clip(rng, n_frames, 1)
    return {"sequence": "clip", "img_frame_ids": np.arange(n_frames), "cam_poses": cam, "cam_intrinsics": K,
            "jointPositions": [X[0].reshape(n_frames, 72)], "poses2d": [p2d[0]],
            "campose_valid": [np.ones(n_frames, bool)]}


@pytest.mark.parametrize("protocol", [0, 2, 4, 5])
def test_a_pickle_that_calls_a_function_is_refused_unrun(tmp_path, protocol):
    marker = tmp_path / "ran"
    doc = _valid_doc(np.random.default_rng(0))
    doc["betas"] = [_Runs(f"touch {marker}")]                      # hidden in a valid sequence dict
    folder = tmp_path / "sequenceFiles" / "test"
    folder.mkdir(parents=True)
    (folder / "clip.pkl").write_bytes(pickle.dumps(doc, protocol=protocol))
    with pytest.raises(InputError, match=r"clip\.pkl: refusing to load (posix|os)\.system") as e:
        read_3dpw(tmp_path)
    assert "\n" not in str(e.value) and not marker.exists()


@pytest.mark.parametrize("protocol", [0, 2, 5])
def test_every_numpy_type_of_a_real_sequence_file_is_read(tmp_path, protocol):
    rng = np.random.default_rng(1)
    doc = _valid_doc(rng)
    doc.update(betas=[np.float32(rng.normal(size=10))], genders=np.array(["m"]), scale=np.float64(2.0),
               trans=[np.asfortranarray(rng.normal(size=(3, 3)))], texture_maps=("a", b"b", {1, 2}))
    path = tmp_path / "clip.pkl"
    path.write_bytes(pickle.dumps(doc, protocol=protocol))
    data = read_sequence(path)
    assert len(data) == 3 and data.clip[0] == "clip"


@pytest.mark.parametrize("change, field", [
    ({"img_frame_ids": np.array([0, 1, 10 ** 30], dtype=object)}, "img_frame_ids"),
    ({"img_frame_ids": np.array([0, 1, -2])}, "img_frame_ids"),
    ({"img_frame_ids": ["a", "b", "c"]}, "img_frame_ids"),
    ({"cam_intrinsics": np.array([["a"] * 3] * 3)}, "cam_intrinsics"),
    ({"cam_poses": np.full((3, 4, 4), np.nan)}, "cam_poses"),
    ({"jointPositions": [np.array([["x"] * 72] * 3)]}, r"jointPositions\[0\]"),
    ({"poses2d": 7}, "poses2d"),
    ({"sequence": "../../outside"}, "sequence"),
    ({"campose_valid": [["yes"] * 3]}, r"campose_valid\[0\]"),
])
def test_bad_values_are_one_line(tmp_path, change, field):
    doc = {**_valid_doc(np.random.default_rng(2)), **change}
    path = tmp_path / "clip.pkl"
    path.write_bytes(pickle.dumps(doc, protocol=2))
    with pytest.raises(InputError, match=rf"clip\.pkl: {field}: ") as e:
        read_sequence(path)
    assert "\n" not in str(e.value)


def test_an_array_larger_than_its_file_is_refused_unallocated(tmp_path):
    # _reconstruct(ndarray, (2**40,), b'b'): a terabyte asked for before any data is read
    hostile = (b"\x80\x02cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\n"
               b"\x8a\x06\x00\x00\x00\x00\x00\x01\x85C\x01b\x87R.")
    path = tmp_path / "big.pkl"
    path.write_bytes(hostile)
    with pytest.raises(InputError, match="more than the file holds"):
        read_sequence(path)


def test_a_fifo_is_refused_without_blocking(tmp_path):
    import os

    folder = tmp_path / "sequenceFiles" / "test"
    folder.mkdir(parents=True)
    os.mkfifo(folder / "clip.pkl")
    with pytest.raises(InputError, match="FIFO"):
        read_3dpw(tmp_path)


def test_the_checkpoint_is_checked_before_the_data_set_is_read(tmp_path):
    import os

    from click.testing import CliRunner

    from mvm.cli.main import main

    marker = tmp_path / "ran"
    folder = tmp_path / "sequenceFiles" / "test"
    folder.mkdir(parents=True)
    (folder / "clip.pkl").write_bytes(pickle.dumps(_Runs(f"touch {marker}"), protocol=2))
    os.mkfifo(tmp_path / "model.pt")
    for checkpoint, problem in (("missing.pt", "file not found"), ("model.pt", "FIFO")):
        result = CliRunner().invoke(main, ["evaluate", "3dpw", str(tmp_path), "--checkpoint",
                                           str(tmp_path / checkpoint)])
        assert result.exit_code == 2 and problem in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(main, ["evaluate", "3dpw", str(tmp_path), "--checkpoint", str(folder / "clip.pkl")])
    assert result.exit_code == 2 and "refusing to load" in result.output and not marker.exists()
