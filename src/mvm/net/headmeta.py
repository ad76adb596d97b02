"""Head metas: the contract between heads, encoders, decoders and losses.

A field has shape ``(B, K, C, H, W)``: ``K`` joints or connections, ``C`` components per
location, ``H × W`` cells of the feature map at ``stride`` pixels per cell. Positions inside
a field are in cell units: cell ``(i, j)`` sits at pixel ``(j · stride, i · stride)``.

- PIF (Parts Intensity Field), ``C = 5``: confidence ``c``, offset ``(p_x, p_y)`` from the
  cell to the closest joint, the spread ``b`` of the adaptive (Laplace) regression loss and
  the Gaussian ``σ`` used to rebuild the high-resolution confidence map.
- PAF (Parts Association Field), ``C = 7``: confidence ``c``, offsets to the connection's
  two joints ``(x1, y1)``, ``(x2, y2)`` and their spreads ``b1``, ``b2``.
- PDF (Parts Depth Field), ``C = 2``: relative depth ``d`` and the radius ``γ`` of the
  Gaussian centred at the joint that the PIF points to.
"""
from __future__ import annotations

from dataclasses import dataclass

from mvm.core.keypoints import BONES, COCO_KEYPOINTS, COCO_SKELETON, FLIP_PERMUTATION

#: Connections beyond the COCO skeleton that skip one joint (nose–shoulder, shoulder–wrist,
#: hip–ankle, hip–opposite knee): a pose stays connected when one joint is missing.
EXTRA_VIRTUAL_CONNECTIONS: tuple[tuple[int, int], ...] = (
    (0, 5), (0, 6), (5, 9), (6, 10), (11, 15), (12, 16), (11, 14), (12, 13),
)
#: The PAF connections: the COCO skeleton and the extra links above. Those that are not bones
#: of the body (face, ear–shoulder and the extra links) are the paper's *virtual* connections.
PAF_CONNECTIONS: tuple[tuple[int, int], ...] = COCO_SKELETON + EXTRA_VIRTUAL_CONNECTIONS
_BONE_SET = {frozenset(b) for b in BONES}
VIRTUAL_CONNECTIONS: tuple[bool, ...] = tuple(frozenset(c) not in _BONE_SET for c in PAF_CONNECTIONS)

PIF_COMPONENTS = ("c", "x", "y", "b", "sigma")
PAF_COMPONENTS = ("c", "x1", "y1", "x2", "y2", "b1", "b2")
PDF_COMPONENTS = ("d", "gamma")


@dataclass(frozen=True)
class PifMeta:
    """Parts Intensity Field: one field per keypoint."""

    keypoints: tuple[str, ...] = COCO_KEYPOINTS
    stride: int = 8
    name: str = "pif"
    components: tuple[str, ...] = PIF_COMPONENTS

    @property
    def n_fields(self) -> int:
        return len(self.keypoints)


@dataclass(frozen=True)
class PafMeta:
    """Parts Association Field: one field per connection ``(joint a, joint b)``."""

    connections: tuple[tuple[int, int], ...] = PAF_CONNECTIONS
    virtual: tuple[bool, ...] = VIRTUAL_CONNECTIONS
    stride: int = 8
    name: str = "paf"
    components: tuple[str, ...] = PAF_COMPONENTS

    @property
    def n_fields(self) -> int:
        return len(self.connections)


@dataclass(frozen=True)
class PdfMeta:
    """Parts Depth Field: one field per keypoint."""

    keypoints: tuple[str, ...] = COCO_KEYPOINTS
    stride: int = 8
    name: str = "pdf"
    components: tuple[str, ...] = PDF_COMPONENTS

    @property
    def n_fields(self) -> int:
        return len(self.keypoints)


@dataclass(frozen=True)
class HeadMetas:
    """The three heads of the network, at one stride."""

    pif: PifMeta
    paf: PafMeta
    pdf: PdfMeta

    @property
    def stride(self) -> int:
        return self.pif.stride

    @classmethod
    def at_stride(cls, stride: int) -> HeadMetas:
        if stride not in (8, 16):
            raise ValueError(f"stride: expected 8 or 16, got {stride}")
        return cls(PifMeta(stride=stride), PafMeta(stride=stride), PdfMeta(stride=stride))


def flip_connections(connections: tuple[tuple[int, int], ...]) -> list[int]:
    """Index permutation of ``connections`` under a left/right swap of the joints.

    ``result[k]`` is the connection that connection ``k`` becomes after a horizontal flip;
    raises ``ValueError`` when the set of connections is not left/right symmetric.
    """
    index = {c: k for k, c in enumerate(connections)}
    out = []
    for a, b in connections:
        fa, fb = int(FLIP_PERMUTATION[a]), int(FLIP_PERMUTATION[b])
        if (fa, fb) in index:
            out.append(index[(fa, fb)])
        elif (fb, fa) in index:
            out.append(index[(fb, fa)])
        else:
            raise ValueError(f"connection {(a, b)} has no mirror image in the list")
    return out
