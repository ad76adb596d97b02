"""Names as a person reads them: frames, images and cameras in their natural order, and the
words a set of camera names shares left out."""
from __future__ import annotations

import re


def natural_key(name: str) -> tuple:
    """Sort key of ``name`` with its runs of digits compared as numbers (``frame_2`` before
    ``frame_10``) and its letters regardless of case (``Cam2`` before ``cam10``); the name itself
    orders names equal so (``a01`` before ``a1``, ``A`` before ``a``).

    >>> sorted(["f_10.jpg", "F_2.jpg", "f_1.jpg", "f_01.jpg", "x", "1"], key=natural_key)
    ['1', 'f_01.jpg', 'f_1.jpg', 'F_2.jpg', 'f_10.jpg', 'x']
    """
    parts = re.split(r"(\d+)", name)                       # digits at the odd places
    return tuple((0, int(p), "") if i % 2 else (1, 0, p.lower()) for i, p in enumerate(parts)), name


def without_shared_words(names: list[str]) -> list[str]:
    """``names`` without the words (runs of letters and digits between ``_``, ``-``, ``.`` or
    spaces) that every one of them begins or ends with: a tool's wrapping of its camera names
    (Pose2Sim's ``int_cam01_img``, anipose's ``calib-camA``). Leading words stay where a name
    would begin with a digit without them (``cam_01`` stays), and every name keeps a word; fewer
    than two names, or names that would no longer differ, stay as they are.

    >>> without_shared_words(["int_cam01_img", "int_cam02_img"])
    ['cam01', 'cam02']
    >>> without_shared_words(["calib-camA", "calib-camB"])
    ['camA', 'camB']
    >>> without_shared_words(["cam_01", "cam_02"]), without_shared_words(["int_cam01_img"])
    (['cam_01', 'cam_02'], ['int_cam01_img'])
    """
    if len(names) < 2:
        return list(names)
    parts = [re.split(r"([_\-. ]+)", name) for name in names]       # words at the even places
    words = min(len(p) + 1 for p in parts) // 2                       # in the shortest name
    lead = 0
    while (lead + 1 < words and len({p[2 * lead] for p in parts}) == 1
           and all(p[2 * lead + 2][:1].isalpha() for p in parts)):
        lead += 1
    trail = 0
    while lead + trail + 1 < words and len({p[-1 - 2 * trail] for p in parts}) == 1:
        trail += 1
    shorter = ["".join(p[2 * lead:len(p) - 2 * trail]) for p in parts]
    return shorter if len(set(shorter)) == len(set(names)) else list(names)
