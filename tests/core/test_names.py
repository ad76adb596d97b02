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
