"""ResNet backbones with torchvision's parameter names; loading a state dict from a file."""
import pytest
import torch

from mvm.errors import InputError
from mvm.net.backbone import ResNet, load_torchvision_state_dict
from mvm.net.model import build_model


def torchvision_resnet18_keys() -> list[str]:
    """The state-dict keys of ``torchvision.models.resnet18()``, written out by hand."""
    bn = ["weight", "bias", "running_mean", "running_var", "num_batches_tracked"]
    keys = ["conv1.weight"] + [f"bn1.{k}" for k in bn]
    for layer in range(1, 5):
        for block in range(2):
            p = f"layer{layer}.{block}"
            keys += [f"{p}.conv1.weight"] + [f"{p}.bn1.{k}" for k in bn]
            keys += [f"{p}.conv2.weight"] + [f"{p}.bn2.{k}" for k in bn]
            if layer > 1 and block == 0:
                keys += [f"{p}.downsample.0.weight"] + [f"{p}.downsample.1.{k}" for k in bn]
    return keys + ["fc.weight", "fc.bias"]


def test_parameter_names_match_torchvision():
    own = set(ResNet("resnet18", stride=32).state_dict())
    expected = set(torchvision_resnet18_keys()) - {"fc.weight", "fc.bias"}
    assert own == expected
    r50 = ResNet("resnet50", stride=32).state_dict()
    assert r50["layer1.0.conv3.weight"].shape == (256, 64, 1, 1)
    assert r50["layer4.2.bn3.running_var"].shape == (2048,)
    assert "layer1.0.downsample.0.weight" in r50  # torchvision projects in the first block


def test_torchvision_state_dict_loads(tmp_path):
    reference = ResNet("resnet18", stride=32).state_dict()
    state = {}
    g = torch.Generator().manual_seed(0)
    for key in torchvision_resnet18_keys():
        shape = reference[key].shape if key in reference else ((1000, 512) if key == "fc.weight" else (1000,))
        dtype = torch.long if key.endswith("num_batches_tracked") else torch.float32
        state[key] = torch.randint(0, 5, shape, generator=g) if dtype == torch.long else torch.randn(shape, generator=g)
    path = tmp_path / "resnet18-imagenet.pth"
    torch.save(state, path)
    model = build_model("resnet18", stride=16)  # dilation keeps every parameter
    report = load_torchvision_state_dict(model.backbone, path)
    assert report["missing"] == [] and report["unexpected"] == []
    assert torch.equal(model.backbone.layer3[1].conv2.weight,
                       state["layer3.1.conv2.weight"])
    assert torch.equal(model.backbone.bn1.running_mean, state["bn1.running_mean"])


def test_wrong_state_dict_is_a_clear_error(tmp_path):
    state = ResNet("resnet18", stride=32).state_dict()
    path = tmp_path / "r18.pt"
    torch.save(state, path)
    with pytest.raises(InputError, match=r"r18.pt: does not fit a torchvision resnet50 .*missing keys: "
                                         r".*shape mismatch keys: .*file \(64, 64, 3, 3\), model \(64, 64, 1, 1\)"):
        load_torchvision_state_dict(ResNet("resnet50", stride=32), path)
    renamed = {k.replace("layer1", "stage1"): v for k, v in state.items()}
    torch.save(renamed, path)
    with pytest.raises(InputError, match="missing keys: layer1.0.bn1.bias"):
        load_torchvision_state_dict(ResNet("resnet18", stride=32), path)
    path.write_text("not a state dict")
    with pytest.raises(InputError, match="not a PyTorch state dict"):
        load_torchvision_state_dict(ResNet("resnet18", stride=32), path)


@pytest.mark.parametrize("stride", [8, 16])
def test_model_output_shapes(stride):
    model = build_model("resnet18", stride=stride, width=8).eval()
    with torch.no_grad():
        out = model(torch.zeros(2, 3, 64, 96))
    h, w = 64 // stride, 96 // stride
    assert out["pif"].shape == (2, 17, 5, h, w)
    assert out["paf"].shape == (2, 27, 7, h, w)
    assert out["pdf"].shape == (2, 17, 2, h, w)


def test_unknown_backbone_lists_the_known_ones():
    with pytest.raises(ValueError, match="resnet18, resnet34, resnet50, resnet101, resnet152"):
        build_model("vgg16")
    with pytest.raises(ValueError, match="stride"):
        build_model("resnet18", stride=4)


@pytest.mark.parametrize("size", [(64, 96), (65, 97), (385, 385)])
def test_upsampling_head_gives_stride_8_fields_from_a_stride_16_backbone(size):
    model = build_model("resnet18", stride=8, width=8, upsample=2).eval()
    assert model.backbone.stride == 16 and model.spec.backbone_stride == 16
    with torch.no_grad():
        out = model(torch.zeros(1, 3, *size))
    h, w = -(-size[0] // 8), -(-size[1] // 8)                       # as the encoder's field_shape
    assert out["pif"].shape == (1, 17, 5, h, w) and out["pdf"].shape == (1, 17, 2, h, w)
    # every upsampled cell starts at the prior confidence, as without upsampling
    assert torch.allclose(out["pif"][0, :, 0], torch.full((17, h, w), out["pif"][0, 0, 0, 0, 0].item()), atol=1e-3)


def test_upsampling_costs_less_than_dilation():
    """Stride 8 by a stride 16 backbone + upsampling head against a backbone dilated to stride 8."""
    from torch.utils.flop_counter import FlopCounterMode

    flops = {}
    for upsample, stride in ((1, 8), (2, 8)):
        model = build_model("resnet50", stride=stride, width=16, upsample=upsample).eval()
        with FlopCounterMode(display=False) as counter, torch.no_grad():
            model(torch.zeros(1, 3, 129, 129))
        flops[upsample] = counter.get_total_flops()
    assert flops[2] < 0.5 * flops[1]
