"""The PIF, PAF and PDF heads: one 1×1 convolution each on the backbone features, optionally
followed by a sub-pixel upsampling (``PixelShuffle``) to a finer field stride.

A head returns its *raw* output ``(B, K, C, H, W)``; :func:`activate` turns it into field
values. Raw channels: confidences are logits, offsets are in cells, and every positive
quantity (``b``, ``σ``, ``d``, ``γ``) is its logarithm, so that the losses stay well
conditioned (the depth loss works on ``log d`` directly).
"""
from __future__ import annotations

import math

import torch
from torch import nn

from mvm.net.headmeta import PafMeta, PdfMeta, PifMeta

#: Components that are positive and predicted as logarithms, per head.
LOG_COMPONENTS = {"pif": (3, 4), "paf": (5, 6), "pdf": (0, 1)}
#: Components that are confidences (logits), per head.
LOGIT_COMPONENTS = {"pif": (0,), "paf": (0,), "pdf": ()}
#: Initial confidence of every location (sets the bias of the confidence logits).
PRIOR_CONFIDENCE = 0.01


class FieldHead(nn.Module):
    """``features: (B, F, H, W)`` -> raw field ``(B, K, C, u·H, u·W)``, ``u = upsample``."""

    def __init__(self, meta: PifMeta | PafMeta | PdfMeta, in_channels: int, upsample: int = 1):
        super().__init__()
        self.meta = meta
        self.n_fields, self.n_components = meta.n_fields, len(meta.components)
        u2 = upsample * upsample
        self.conv = nn.Conv2d(in_channels, self.n_fields * self.n_components * u2, 1)
        self.upsample = nn.PixelShuffle(upsample) if upsample > 1 else nn.Identity()
        nn.init.normal_(self.conv.weight, std=0.01)
        bias = torch.zeros(self.n_fields, self.n_components)
        for k in LOGIT_COMPONENTS[meta.name]:
            bias[:, k] = math.log(PRIOR_CONFIDENCE / (1 - PRIOR_CONFIDENCE))
        with torch.no_grad():
            self.conv.bias.copy_(bias.reshape(-1).repeat_interleave(u2))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        x = self.upsample(self.conv(features))
        B, _, H, W = x.shape
        return x.reshape(B, self.n_fields, self.n_components, H, W)


def activate(name: str, raw: torch.Tensor) -> torch.Tensor:
    """Raw head output ``(B, K, C, H, W)`` -> field values of the same shape.

    Confidences go through a sigmoid, log-parameterized components through ``exp``; offsets
    are returned unchanged.
    """
    if name not in LOG_COMPONENTS:
        raise ValueError(f"head {name!r}: expected one of {', '.join(LOG_COMPONENTS)}")
    out = raw.clone()
    for k in LOGIT_COMPONENTS[name]:
        out[:, :, k] = torch.sigmoid(raw[:, :, k])
    for k in LOG_COMPONENTS[name]:
        out[:, :, k] = torch.exp(raw[:, :, k].clamp(-10.0, 10.0))
    return out
