"""ResNet backbones in plain PyTorch, with torchvision's parameter names.

The modules are named as in ``torchvision.models.resnet`` (``conv1``, ``bn1``,
``layer1`` … ``layer4``, blocks ``conv1..3``, ``bn1..3``, ``downsample.0/1``), so an
ImageNet state dict saved from torchvision loads with :func:`load_torchvision_state_dict`.
The classifier (``fc``) is not part of the backbone: its keys are accepted and dropped.

``width`` scales every channel count (64 for the standard networks); a smaller width gives
the small networks used for tests and CPU demonstrations (those do not load ImageNet weights).
"""
from __future__ import annotations

import logging
from pathlib import Path

import torch
from torch import nn

from mvm.errors import InputError

LOG = logging.getLogger(__name__)

#: name -> (block type, blocks per stage)
ARCHITECTURES = {
    "resnet18": ("basic", (2, 2, 2, 2)),
    "resnet34": ("basic", (3, 4, 6, 3)),
    "resnet50": ("bottleneck", (3, 4, 6, 3)),
    "resnet101": ("bottleneck", (3, 4, 23, 3)),
    "resnet152": ("bottleneck", (3, 8, 36, 3)),
}


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, inplanes: int, planes: int, stride: int = 1, dilation: int = 1,
                 downsample: nn.Module | None = None):
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride, padding=dilation, dilation=dilation, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, padding=dilation, dilation=dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class Bottleneck(nn.Module):
    expansion = 4

    def __init__(self, inplanes: int, planes: int, stride: int = 1, dilation: int = 1,
                 downsample: nn.Module | None = None):
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        # torchvision (v1.5) puts the stride on the 3x3 convolution
        self.conv2 = nn.Conv2d(planes, planes, 3, stride, padding=dilation, dilation=dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, planes * 4, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(planes * 4)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


class ResNet(nn.Module):
    """ResNet feature extractor. ``images: (B, 3, H, W)`` -> ``(B, out_channels, H/s, W/s)``.

    Args:
        name: one of ``ARCHITECTURES``.
        stride: output stride, 8, 16 or 32; strides below 32 replace the stride of the last
            stages by dilation (as torchvision's ``replace_stride_with_dilation``), which keeps
            every parameter, so ImageNet weights still apply.
        width: channels of the stem (64 in the standard networks).
    """

    def __init__(self, name: str = "resnet50", stride: int = 16, width: int = 64):
        super().__init__()
        if name not in ARCHITECTURES:
            raise ValueError(f"backbone {name!r}: expected one of {', '.join(ARCHITECTURES)}")
        if stride not in (8, 16, 32):
            raise ValueError(f"stride: expected 8, 16 or 32, got {stride}")
        if width < 4:
            raise ValueError(f"width: expected at least 4, got {width}")
        kind, layers = ARCHITECTURES[name]
        block = BasicBlock if kind == "basic" else Bottleneck
        self.name, self.stride, self.width = name, stride, width
        self.inplanes, self.dilation = width, 1
        self.conv1 = nn.Conv2d(3, width, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        dilate = {32: (False, False, False), 16: (False, False, True), 8: (False, True, True)}[stride]
        self.layer1 = self._make_layer(block, width, layers[0])
        self.layer2 = self._make_layer(block, 2 * width, layers[1], 2)
        self.layer3 = self._make_layer(block, 4 * width, layers[2], 2, dilate[1])
        self.layer4 = self._make_layer(block, 8 * width, layers[3], 2, dilate[2])
        self.out_channels = 8 * width * block.expansion
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def _make_layer(self, block, planes: int, blocks: int, stride: int = 1, dilate: bool = False) -> nn.Sequential:
        previous_dilation = self.dilation
        if dilate:
            self.dilation *= stride
            stride = 1
        downsample = None
        if stride != 1 or self.inplanes != planes * block.expansion:
            downsample = nn.Sequential(
                nn.Conv2d(self.inplanes, planes * block.expansion, 1, stride, bias=False),
                nn.BatchNorm2d(planes * block.expansion),
            )
        layers = [block(self.inplanes, planes, stride, previous_dilation, downsample)]
        self.inplanes = planes * block.expansion
        layers += [block(self.inplanes, planes, dilation=self.dilation) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        return self.layer4(self.layer3(self.layer2(self.layer1(x))))


#: Keys of a torchvision classifier that the backbone does not use.
CLASSIFIER_KEYS = ("fc.weight", "fc.bias")


def load_torchvision_state_dict(backbone: ResNet, path: str | Path, strict: bool = True) -> dict:
    """Load a torchvision ResNet state dict (a ``.pt``/``.pth`` file of tensors) into ``backbone``.

    Keys may carry a ``module.`` (DataParallel) or ``backbone.`` prefix. The classifier keys
    (``fc.*``) are dropped. Every other key must exist in the backbone with the same shape.

    Returns ``{"missing": [...], "unexpected": [...], "loaded": n}``. With ``strict`` any missing
    or unexpected key, or a shape mismatch, raises an :class:`InputError` naming the file, the
    first few offending keys and the architecture expected.
    """
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except Exception as e:  # torch raises several types for a file that is not a state dict
        raise InputError(path, None, f"not a PyTorch state dict: {e}") from None
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(path, None, "expected a dict of tensors (a state_dict)")
    state = {_strip_prefix(k): v for k, v in state.items() if _strip_prefix(k) not in CLASSIFIER_KEYS}
    own = backbone.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    mismatched = sorted(k for k in set(own) & set(state) if own[k].shape != state[k].shape)
    report = {"missing": missing, "unexpected": unexpected, "mismatched": mismatched,
              "loaded": len(set(own) & set(state)) - len(mismatched)}
    what = f"{backbone.name} (width {backbone.width})"
    if strict and (missing or unexpected or mismatched):
        parts = []
        for label, keys in (("missing", missing), ("unexpected", unexpected), ("shape mismatch", mismatched)):
            if keys:
                shown = ", ".join(keys[:4]) + (f" … ({len(keys)} in all)" if len(keys) > 4 else "")
                if label == "shape mismatch":
                    k = keys[0]
                    shown += f" (e.g. {k}: file {tuple(state[k].shape)}, model {tuple(own[k].shape)})"
                parts.append(f"{label} keys: {shown}")
        raise InputError(path, None, f"does not fit a torchvision {what}: " + "; ".join(parts))
    backbone.load_state_dict({k: v for k, v in state.items() if k in own and k not in mismatched}, strict=False)
    LOG.info("loaded %d tensors into %s from %s (%d missing, %d unexpected)",
             report["loaded"], what, path, len(missing), len(unexpected))
    return report


def _strip_prefix(key: str) -> str:
    for prefix in ("module.", "backbone."):
        if key.startswith(prefix):
            key = key[len(prefix):]
    return key
