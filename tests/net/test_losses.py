"""Every loss term against a value computed by hand."""
import math

import numpy as np
import pytest
import torch

from mvm.net import losses


def _nan(*shape):
    return torch.full(shape, float("nan"))


def test_confidence_loss_by_hand():
    logits = torch.tensor([2.0, -1.0, 0.5, 3.0]).view(1, 1, 2, 2)
    target = torch.tensor([1.0, 0.0, float("nan"), 0.0]).view(1, 1, 2, 2)
    bce = [-math.log(1 / (1 + math.exp(-2.0))), -math.log(1 - 1 / (1 + math.exp(1.0))),
           -math.log(1 - 1 / (1 + math.exp(-3.0)))]
    assert losses.confidence_loss(logits, target).item() == pytest.approx(sum(bce) / 3, rel=1e-6)
    # background weight 0.5: (1·bce0 + 0.5·bce1 + 0.5·bce3) / 2
    assert losses.confidence_loss(logits, target, 0.5).item() == pytest.approx(
        (bce[0] + 0.5 * bce[1] + 0.5 * bce[2]) / 2.0, rel=1e-6)


def test_laplace_loss_by_hand():
    pred = torch.tensor([[0.0, 0.0], [1.0, 1.0]]).T.reshape(1, 1, 2, 1, 2)    # cells: (0,0), (1,1)
    target = torch.tensor([[3.0, 4.0], [float("nan"), float("nan")]]).T.reshape(1, 1, 2, 1, 2)
    log_b = torch.tensor([math.log(2.0), 0.0]).view(1, 1, 1, 2)
    # only the first cell has a target: |(3, 4)| / 2 + log 2
    assert losses.laplace_loss(pred, target, log_b).item() == pytest.approx(5 / 2 + math.log(2), rel=1e-6)


def test_log_l1_by_hand():
    raw = torch.tensor([0.0, 1.0, 5.0]).view(1, 1, 1, 3)
    target = torch.tensor([math.e, 1.0, float("nan")]).view(1, 1, 1, 3)
    assert losses.log_l1_loss(raw, target).item() == pytest.approx((1 + 1) / 2, rel=1e-6)


def test_scale_invariant_depth_loss_by_hand():
    """The paper's Eq.: 1/N Σ r² − 1/N² (Σ r)², r = log(d_pred / d_true), per person, averaged."""
    pred = torch.tensor([1.0, 2.0, 4.0, 3.0, 3.0, 7.0])
    true = torch.tensor([1.0, 1.0, 1.0, 1.5, 1.5, float("nan")])
    groups = torch.tensor([0, 0, 0, 1, 1, 1])
    raw = torch.log(pred).view(1, 1, 1, 6)
    r0 = [math.log(1.0), math.log(2.0), math.log(4.0)]
    var0 = sum(x * x for x in r0) / 3 - (sum(r0) / 3) ** 2
    var1 = 0.0  # both cells have the same ratio 2: any common scale is free
    value = losses.scale_invariant_depth_loss(raw, true.view(1, 1, 1, 6), groups.view(1, 1, 1, 6), per="person")
    assert value.item() == pytest.approx((var0 + var1) / 2, rel=1e-6)
    # the paper's image-level loss: one variance over the five labelled cells of the image
    r = r0 + [math.log(2.0), math.log(2.0)]
    var = sum(x * x for x in r) / 5 - (sum(r) / 5) ** 2
    value = losses.scale_invariant_depth_loss(raw, true.view(1, 1, 1, 6), groups.view(1, 1, 1, 6))
    assert value.item() == pytest.approx(var, rel=1e-6)


def test_depth_log_scale_divides_the_residuals_by_hand():
    """With ``log_scale`` s: Var[r / s] = Var[r] / s², r = log(d_pred / d_true), per person."""
    pred = torch.tensor([1.0, 1.1, 0.9, 2.0, 2.0])
    true = torch.tensor([1.0, 1.0, 1.0, 1.0, 1.2])
    groups = torch.tensor([0, 0, 0, 1, 1])
    r0 = [0.0, math.log(1.1) / 0.1, math.log(0.9) / 0.1]
    r1 = [math.log(2.0) / 0.1, math.log(2.0 / 1.2) / 0.1]
    var = [sum(x * x for x in r) / len(r) - (sum(r) / len(r)) ** 2 for r in (r0, r1)]
    value = losses.scale_invariant_depth_loss(torch.log(pred).view(1, 1, 1, 5), true.view(1, 1, 1, 5),
                                              groups.view(1, 1, 1, 5), log_scale=0.1, per="person")
    assert value.item() == pytest.approx((var[0] + var[1]) / 2, rel=1e-5)
    # the same through total_loss: pdf_depth of LossWeights(depth_log_scale=0.1)
    raw = {"pif": torch.zeros(1, 17, 5, 1, 5), "paf": torch.zeros(1, 27, 7, 1, 5), "pdf": torch.zeros(1, 17, 2, 1, 5)}
    targets = {"pif": _nan(1, 17, 5, 1, 5), "paf": _nan(1, 27, 7, 1, 5), "pdf": _nan(1, 17, 2, 1, 5),
               "pdf_group": torch.full((1, 17, 1, 5), -1)}
    raw["pdf"][0, 3, 0, 0] = torch.log(pred)
    targets["pdf"][0, 3, 0, 0] = true
    targets["pdf_group"][0, 3, 0] = groups
    _, parts = losses.total_loss(raw, targets, losses.LossWeights(depth_log_scale=0.1, depth_loss="person"))
    assert parts["pdf_depth"] == pytest.approx((var[0] + var[1]) / 2, rel=1e-5)


def test_depth_loss_is_scale_invariant_per_person_and_batch():
    torch.manual_seed(0)
    raw = torch.randn(2, 17, 4, 4)
    true = torch.rand(2, 17, 4, 4) + 0.5
    groups = torch.randint(0, 3, (2, 17, 4, 4))
    base = losses.scale_invariant_depth_loss(raw, true, groups, per="person")
    # multiply the prediction of one person of one image by a constant: unchanged
    shifted = raw + torch.where((groups == 1) & (torch.arange(2).view(2, 1, 1, 1) == 0), 0.7, 0.0)
    assert (losses.scale_invariant_depth_loss(shifted, true, groups, per="person").item()
            == pytest.approx(base.item(), rel=1e-5))
    # the same group index in two images is two persons
    img0 = losses.scale_invariant_depth_loss(raw[:1], true[:1], groups[:1], per="person")
    img1 = losses.scale_invariant_depth_loss(raw[1:], true[1:], groups[1:], per="person")
    assert base.item() == pytest.approx((img0.item() + img1.item()) / 2, rel=1e-5)


def _two_people(depth_a: float, depth_b: float):
    """One image, two people of 17 joints: log-depth predictions equal to the truth, where the
    truth puts person 0 at ``depth_a`` and person 1 at ``depth_b`` (one reference per image)."""
    profile = torch.linspace(0.95, 1.05, 17)
    true = torch.full((1, 17, 2, 2), float("nan"))
    groups = torch.full((1, 17, 2, 2), -1)
    true[0, :, 0, 0], groups[0, :, 0, 0] = depth_a * profile, 0
    true[0, :, 1, 1], groups[0, :, 1, 1] = depth_b * profile, 1
    return true, groups


def test_image_level_depth_loss_keeps_the_order_of_people():
    true, groups = _two_people(1.0, 2.0)
    exact = torch.log(torch.nan_to_num(true, nan=1.0))
    assert losses.scale_invariant_depth_loss(exact, true, groups).item() == pytest.approx(0.0, abs=1e-5)
    # a global scale of the prediction (or of the truth) changes nothing
    assert losses.scale_invariant_depth_loss(exact + math.log(3.7), true, groups).item() == pytest.approx(0.0, abs=1e-5)
    assert losses.scale_invariant_depth_loss(exact, true * 0.2, groups).item() == pytest.approx(0.0, abs=1e-5)
    # swapping the two people's depths: the per-person loss does not see it, the image loss does
    swapped, _ = _two_people(2.0, 1.0)
    raw = torch.log(torch.nan_to_num(swapped, nan=1.0))
    assert losses.scale_invariant_depth_loss(raw, true, groups, per="person").item() == pytest.approx(0.0, abs=1e-5)
    # residuals are +log 2 on 17 cells and -log 2 on 17: variance (log 2)^2
    assert losses.scale_invariant_depth_loss(raw, true, groups).item() == pytest.approx(math.log(2.0) ** 2, rel=1e-5)
    with pytest.raises(ValueError, match="image, person"):
        losses.scale_invariant_depth_loss(raw, true, groups, per="joint")


def test_missing_fields_weigh_nothing():
    raw = {"pif": torch.randn(1, 17, 5, 3, 3, requires_grad=True), "paf": torch.randn(1, 27, 7, 3, 3),
           "pdf": torch.randn(1, 17, 2, 3, 3, requires_grad=True)}
    targets = {"pif": _nan(1, 17, 5, 3, 3), "paf": _nan(1, 27, 7, 3, 3), "pdf": _nan(1, 17, 2, 3, 3),
               "pdf_group": torch.full((1, 17, 3, 3), -1)}
    total, parts = losses.total_loss(raw, targets)
    assert total.item() == 0.0 and all(v == 0.0 for v in parts.values())
    total.backward()
    assert raw["pdf"].grad is not None and float(raw["pdf"].grad.abs().sum()) == 0.0


def test_total_loss_combines_terms_with_lambdas():
    torch.manual_seed(1)
    raw = {"pif": torch.randn(2, 17, 5, 4, 4), "paf": torch.randn(2, 27, 7, 4, 4), "pdf": torch.randn(2, 17, 2, 4, 4)}
    targets = {"pif": torch.randn(2, 17, 5, 4, 4), "paf": torch.randn(2, 27, 7, 4, 4),
               "pdf": torch.rand(2, 17, 2, 4, 4) + 0.1, "pdf_group": torch.randint(-1, 2, (2, 17, 4, 4))}
    targets["pif"][:, :, 0] = (targets["pif"][:, :, 0] > 0).float()
    targets["paf"][:, :, 0] = (targets["paf"][:, :, 0] > 0).float()
    w = losses.LossWeights(pif=0.5, paf=2.0, pdf=3.0)
    total, p = losses.total_loss(raw, targets, w)
    l_pif = p["pif_c"] + p["pif_reg"] + p["pif_scale"]
    l_paf = p["paf_c"] + p["paf_reg"]
    l_pdf = p["pdf_depth"] + p["pdf_gamma"]
    assert p["L_PIF"] == pytest.approx(l_pif, rel=1e-5) and p["L_PDF"] == pytest.approx(l_pdf, rel=1e-5)
    assert total.item() == pytest.approx(0.5 * l_pif + 2.0 * l_paf + 3.0 * l_pdf, rel=1e-5)
    # the depth term equals the per-image variance computed in numpy (per person as an option)
    r = (raw["pdf"][:, :, 0] - torch.log(targets["pdf"][:, :, 0])).numpy()
    g = targets["pdf_group"].numpy()
    assert p["pdf_depth"] == pytest.approx(float(np.mean([r[b][g[b] >= 0].var() for b in range(2)])), rel=1e-4)
    variances = [r[b][g[b] == k].var() for b in range(2) for k in range(2) if (g[b] == k).any()]
    _, p = losses.total_loss(raw, targets, losses.LossWeights(depth_loss="person"))
    assert p["pdf_depth"] == pytest.approx(float(np.mean(variances)), rel=1e-4)
