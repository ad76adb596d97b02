"""The loss of the paper: ``L = λ1·L_PIF + λ2·L_PAF + λ3·L_PDF``.

Each term averages over the locations that have a target (the NaNs of the encoder's targets
carry zero weight, so 2D-only data leave the PDF untouched and missing joints are ignored):

- ``L_PIF`` = confidence (binary cross-entropy) + Laplace regression of the offset
  (``‖Δ‖ / b + log b``, ``b`` the predicted spread) + L1 on ``log σ``;
- ``L_PAF`` = confidence + Laplace regression of both end points;
- ``L_PDF`` = the scale-invariant depth loss of the paper, the variance of the log depth ratios
  ``Var[log d_pred − log d_true] = 1/N Σ r² − 1/N² (Σ r)²`` over all labelled cells of one
  image (relative depths carry no scale, so the variance ignores a factor common to the image,
  but not the order of its people in depth), averaged over the images of the batch; plus L1
  on ``log γ``. The ``'person'`` variant takes one variance per person instead (each person's
  depth profile only, blind to who stands in front of whom). The log-depth residuals may be divided by a
  ``depth_log_scale`` first: relative depths within a person vary by a few per cent, so the
  raw variance is of order 1e-3 and its gradient is tiny beside the other terms; dividing by
  the typical spread of relative log depths (e.g. 0.1) brings it to order 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from mvm.core.config import check_settings, setting

#: Clamp of the log-spreads in the Laplace loss (keeps ``exp(-log b)`` finite early on).
LOG_SPREAD_RANGE = (-5.0, 5.0)
#: Groups of cells over which the depth loss takes one variance: 'image' (the paper) or 'person'.
DEPTH_LOSSES = ("image", "person")


@dataclass(frozen=True)
class LossWeights:
    """λ1, λ2, λ3 of the paper's loss and how its terms are weighed."""

    #: λ1, the weight of the PIF (joint) loss; higher favours joint localisation. [1]
    pif: float = setting(1.0, ge=0)
    #: λ2, the weight of the PAF (connection) loss. [1]
    paf: float = setting(1.0, ge=0)
    #: λ3, the weight of the PDF (depth) loss. [1]
    pdf: float = setting(1.0, ge=0)
    #: Weight of background cells in the confidence losses; lower makes the few positive cells
    #: count more. [1]
    background: float = setting(1.0, ge=0)
    #: Unit of the log-depth residuals in the depth loss (1: the paper's unnormalized variance). [1]
    depth_log_scale: float = setting(1.0, gt=0)
    #: Groups of cells over which the depth loss takes one variance: "image" (the paper) or
    #: "person". [name]
    depth_loss: str = setting("image", choices=DEPTH_LOSSES)

    def __post_init__(self):
        check_settings(self)


def masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of ``values[mask]``; 0 (with a gradient path) when the mask is empty."""
    if mask.any():
        return values[mask].mean()
    return values.sum() * 0.0


def confidence_loss(logits: torch.Tensor, target: torch.Tensor, background_weight: float = 1.0) -> torch.Tensor:
    """Weighted binary cross-entropy over the cells whose target is not NaN. Shapes ``(B, K, H, W)``.

    ``Σ w·BCE / Σ w`` with ``w = 1`` on positive cells and ``background_weight`` on the others.
    """
    mask = torch.isfinite(target)
    t = torch.nan_to_num(target, nan=0.0)
    bce = F.binary_cross_entropy_with_logits(logits, t, reduction="none")
    w = torch.where(t > 0, torch.ones_like(t), torch.full_like(t, background_weight)) * mask
    total = w.sum()
    if total <= 0:
        return logits.sum() * 0.0
    return (w * bce).sum() / total


def laplace_loss(pred: torch.Tensor, target: torch.Tensor, log_b: torch.Tensor) -> torch.Tensor:
    """Adaptive regression loss ``‖pred − target‖ / b + log b`` over cells with a target.

    ``pred, target: (B, K, 2, H, W)`` offsets, ``log_b: (B, K, H, W)``.
    """
    mask = torch.isfinite(target).all(dim=2)
    norm = torch.linalg.vector_norm(pred - torch.nan_to_num(target, nan=0.0), dim=2)
    lb = log_b.clamp(*LOG_SPREAD_RANGE)
    return masked_mean(norm * torch.exp(-lb) + lb, mask)


def log_l1_loss(raw_log: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``|raw_log − log target|`` over cells with a positive target. Shapes ``(B, K, H, W)``."""
    mask = torch.isfinite(target) & (torch.nan_to_num(target, nan=0.0) > 0)
    t = torch.log(torch.where(mask, target, torch.ones_like(target)))
    return masked_mean((raw_log - t).abs(), mask)


def scale_invariant_depth_loss(raw_log_d: torch.Tensor, target: torch.Tensor, groups: torch.Tensor,
                               log_scale: float = 1.0, per: str = "image") -> torch.Tensor:
    """The paper's ``L_PDF``: mean over groups of ``Var[(log d_pred − log d_true) / log_scale]``.

    Args:
        raw_log_d: ``(B, K, H, W)`` predicted log depth.
        target: ``(B, K, H, W)`` relative depth, NaN (or ≤ 0) where unknown; the depths of one
            image share one reference (see :mod:`mvm.net.supervision`).
        groups: ``(B, K, H, W)`` integer group of each cell within its image (the person), -1: none.
        log_scale: unit of the log-depth residuals (1: the paper's loss as written).
        per: ``'image'``: one variance over all labelled cells of an image (the paper);
            ``'person'``: one variance per person.
    Returns:
        scalar; 0 when no cell has a depth.
    """
    if per not in DEPTH_LOSSES:
        raise ValueError(f"per: expected one of {', '.join(DEPTH_LOSSES)}, got {per!r}")
    mask = torch.isfinite(target) & (torch.nan_to_num(target, nan=0.0) > 0) & (groups >= 0)
    if not mask.any():
        return raw_log_d.sum() * 0.0
    B = raw_log_d.shape[0]
    batch = torch.arange(B, device=groups.device).view(B, 1, 1, 1).expand_as(groups)
    if per == "image":
        key = batch[mask]
    else:
        key = (batch * (int(groups.max().item()) + 1) + groups)[mask]
    _, inverse = torch.unique(key, return_inverse=True)
    r = (raw_log_d[mask] - torch.log(target[mask])) / log_scale
    G = int(inverse.max().item()) + 1
    count = torch.zeros(G, dtype=r.dtype, device=r.device).index_add_(0, inverse, torch.ones_like(r))
    s1 = torch.zeros(G, dtype=r.dtype, device=r.device).index_add_(0, inverse, r)
    s2 = torch.zeros(G, dtype=r.dtype, device=r.device).index_add_(0, inverse, r * r)
    variance = s2 / count - (s1 / count) ** 2
    return variance.mean()


def pif_loss(raw: torch.Tensor, target: torch.Tensor, background_weight: float = 1.0) -> dict[str, torch.Tensor]:
    """``raw, target: (B, 17, 5, H, W)`` -> ``{"pif_c", "pif_reg", "pif_scale"}``."""
    return {"pif_c": confidence_loss(raw[:, :, 0], target[:, :, 0], background_weight),
            "pif_reg": laplace_loss(raw[:, :, 1:3], target[:, :, 1:3], raw[:, :, 3]),
            "pif_scale": log_l1_loss(raw[:, :, 4], target[:, :, 4])}


def paf_loss(raw: torch.Tensor, target: torch.Tensor, background_weight: float = 1.0) -> dict[str, torch.Tensor]:
    """``raw, target: (B, C, 7, H, W)`` -> ``{"paf_c", "paf_reg"}`` (both end points)."""
    return {"paf_c": confidence_loss(raw[:, :, 0], target[:, :, 0], background_weight),
            "paf_reg": laplace_loss(raw[:, :, 1:3], target[:, :, 1:3], raw[:, :, 5])
            + laplace_loss(raw[:, :, 3:5], target[:, :, 3:5], raw[:, :, 6])}


def pdf_loss(raw: torch.Tensor, target: torch.Tensor, groups: torch.Tensor,
             depth_log_scale: float = 1.0, per: str = "image") -> dict[str, torch.Tensor]:
    """``raw, target: (B, 17, 2, H, W)``, ``groups: (B, 17, H, W)`` -> ``{"pdf_depth", "pdf_gamma"}``."""
    return {"pdf_depth": scale_invariant_depth_loss(raw[:, :, 0], target[:, :, 0], groups, depth_log_scale, per),
            "pdf_gamma": log_l1_loss(raw[:, :, 1], target[:, :, 1])}


def total_loss(raw: dict[str, torch.Tensor], targets: dict[str, torch.Tensor],
               weights: LossWeights = LossWeights()) -> tuple[torch.Tensor, dict[str, float]]:
    """``L = λ1·L_PIF + λ2·L_PAF + λ3·L_PDF``; returns the total and every component (floats)."""
    parts = {**pif_loss(raw["pif"], targets["pif"], weights.background),
             **paf_loss(raw["paf"], targets["paf"], weights.background),
             **pdf_loss(raw["pdf"], targets["pdf"], targets["pdf_group"], weights.depth_log_scale,
                       weights.depth_loss)}
    l_pif = parts["pif_c"] + parts["pif_reg"] + parts["pif_scale"]
    l_paf = parts["paf_c"] + parts["paf_reg"]
    l_pdf = parts["pdf_depth"] + parts["pdf_gamma"]
    total = weights.pif * l_pif + weights.paf * l_paf + weights.pdf * l_pdf
    summary = {k: float(v.detach()) for k, v in parts.items()}
    summary.update(L_PIF=float(l_pif.detach()), L_PAF=float(l_paf.detach()), L_PDF=float(l_pdf.detach()),
                   total=float(total.detach()))
    return total, summary
