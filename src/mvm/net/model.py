"""The network: a ResNet backbone and the PIF, PAF and PDF heads, built from a name."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from mvm.net.backbone import ARCHITECTURES, ResNet
from mvm.net.headmeta import HeadMetas
from mvm.net.heads import FieldHead, activate

#: ImageNet normalization expected by torchvision weights (RGB, images in [0, 1]).
IMAGE_MEAN = (0.485, 0.456, 0.406)
IMAGE_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class ModelSpec:
    """Everything needed to rebuild a network (stored in checkpoint metadata).

    Attributes:
        backbone: a name of ``ARCHITECTURES`` (``resnet18`` … ``resnet152``).
        stride: 8 or 16, pixels per field cell.
        width: stem channels of the backbone (64 for ImageNet weights; smaller for CPU demos).
        upsample: 1 or 2. With 2 the backbone runs at ``2 · stride`` and the heads upsample
            their fields (a sub-pixel convolution, as PifPaf): stride 8 fields from a stride 16
            backbone cost about 87 GFLOP per 385² image with ResNet-152, against 286 when the
            backbone itself reaches stride 8 by dilation (``upsample = 1``).
    """

    backbone: str = "resnet50"
    stride: int = 16
    width: int = 64
    upsample: int = 1

    @property
    def backbone_stride(self) -> int:
        """Output stride of the backbone; network inputs are padded to a multiple of it."""
        return self.stride * self.upsample

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelSpec:
        unknown = set(d) - {"backbone", "stride", "width", "upsample"}
        if unknown:
            raise ValueError(f"model spec: unknown keys {sorted(unknown)}")
        return cls(**d)


class PoseNet(nn.Module):
    """``images: (B, 3, H, W)`` normalized -> ``{"pif": (B, 17, 5, h, w), "paf": (B, 27, 7, h, w),
    "pdf": (B, 17, 2, h, w)}`` raw fields, ``h = ceil(H / stride)``.
    """

    def __init__(self, spec: ModelSpec):
        super().__init__()
        if spec.backbone not in ARCHITECTURES:
            raise ValueError(f"backbone {spec.backbone!r}: expected one of {', '.join(ARCHITECTURES)}")
        if spec.upsample not in (1, 2):
            raise ValueError(f"upsample: expected 1 or 2, got {spec.upsample}")
        self.spec = spec
        self.metas = HeadMetas.at_stride(spec.stride)
        self.backbone = ResNet(spec.backbone, spec.backbone_stride, spec.width)
        c = self.backbone.out_channels
        self.pif = FieldHead(self.metas.pif, c, spec.upsample)
        self.paf = FieldHead(self.metas.paf, c, spec.upsample)
        self.pdf = FieldHead(self.metas.pdf, c, spec.upsample)

    def forward(self, images: torch.Tensor) -> dict[str, torch.Tensor]:
        features = self.backbone(images)
        h, w = -(-images.shape[-2] // self.spec.stride), -(-images.shape[-1] // self.spec.stride)
        return {name: getattr(self, name)(features)[..., :h, :w] for name in ("pif", "paf", "pdf")}


def build_model(backbone: str = "resnet50", stride: int = 16, width: int = 64, upsample: int = 1) -> PoseNet:
    """Build the network by name; e.g. ``build_model("resnet152", stride=8, upsample=2)``."""
    return PoseNet(ModelSpec(backbone, stride, width, upsample))


def fields_from_raw(raw: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Activate every head's raw output (see :func:`mvm.net.heads.activate`)."""
    return {name: activate(name, value) for name, value in raw.items()}

