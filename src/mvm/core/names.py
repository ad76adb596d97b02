"""The natural order of names: frames, images and cameras as a person lists them."""
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
