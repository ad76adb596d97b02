"""The one natural order of frame, image and camera names."""
from __future__ import annotations

from mvm.core.association import frame_sequence
from mvm.core.names import natural_key


def test_numbers_compare_as_numbers_letters_regardless_of_case():
    names = ["frame_10.jpg", "Frame_9.jpg", "frame_100.jpg", "frame_1.jpg", "cam10", "Cam2", "cam1"]
    assert sorted(names, key=natural_key) == ["cam1", "Cam2", "cam10", "frame_1.jpg", "Frame_9.jpg",
                                              "frame_10.jpg", "frame_100.jpg"]


def test_names_equal_but_for_case_or_zeros_keep_a_fixed_order():
    for names in (["a1", "a01"], ["a01", "a1"]):
        assert sorted(names, key=natural_key) == ["a01", "a1"]
    assert sorted(["b", "B"], key=natural_key) == ["B", "b"]


def test_any_file_name_has_a_place():
    """A superscript two counts as a digit for ``str.isdigit`` but not for ``int``; Arabic-Indic
    digits are digits for both: no name makes the sort raise."""
    names = ["f_1²2.jpg", "f_١٢.jpg", "f_3.jpg", "²", ""]
    assert sorted(names, key=natural_key) == ["", "f_1²2.jpg", "f_3.jpg", "f_١٢.jpg", "²"]


def test_the_video_order_is_the_natural_order():
    names = ["f_10.jpg", "F_2.jpg", "f_1.jpg"]
    assert frame_sequence(names).tolist() == [2, 1, 0]


def test_shared_words_of_camera_names_left_out():
    """Pose2Sim's and anipose's wrapping goes; a name never loses its last word, nor begins with
    a digit where it did not."""
    from mvm.core.names import without_shared_words

    assert without_shared_words(["int_cam01_img", "int_cam02_img", "int_cam10_img"]) == ["cam01", "cam02", "cam10"]
    assert without_shared_words(["vid_v1_cam1", "vid_v1_cam2"]) == ["cam1", "cam2"]
    assert without_shared_words(["calib-camA", "calib-camB"]) == ["camA", "camB"]
    assert without_shared_words(["cam01_ext", "cam02_ext"]) == ["cam01", "cam02"]
    assert without_shared_words(["cam_01", "cam_02"]) == ["cam_01", "cam_02"]            # not "01", "02"
    assert without_shared_words(["a_x", "a_x_x"]) == ["x", "x_x"]                        # a word stays
    assert without_shared_words(["a_b", "a__b"]) == ["a_b", "a__b"]                      # still two names
    assert without_shared_words(["left", "right"]) == ["left", "right"]
    assert without_shared_words(["int_cam01_img"]) == ["int_cam01_img"]
    assert without_shared_words([]) == []
