"""Tests of network/checkpoint.py: the model round trip, one-line errors, parameter hashes."""

import pytest
import torch

from network.checkpoint import CHECKPOINT_FORMAT, load_checkpoint, params_sha256, save_checkpoint
from network.config import get_config
from network.model.polar_model import PolarInverseModel


def test_round_trip_and_default_input_variant(tmp_path):
    torch.manual_seed(0)
    model = PolarInverseModel(get_config("toy"))
    path = tmp_path / "model.pt"
    save_checkpoint(path, {"format": CHECKPOINT_FORMAT, "config": model.config.to_dict(), "model": model.state_dict()})
    assert [p.name for p in tmp_path.iterdir()] == ["model.pt"]  # no temporary file left behind
    loaded, ckpt = load_checkpoint(path)
    assert not loaded.training and loaded.config == model.config
    assert ckpt["inputs"] == "full"  # files without a variant were trained on all nine maps
    assert params_sha256(loaded.state_dict()) == params_sha256(model.state_dict())


def test_loading_skips_the_random_init_and_equals_an_initialised_model(monkeypatch):
    """``load_checkpoint`` constructs without the random init (it would be overwritten at once): no fill runs,
    and the loaded model (parameters, persistent and computed buffers, outputs) equals one initialised and then
    loaded. Measured on the shipped model: construction 0.31-0.48 s with the init, 0.02 s without
    (docs/measurements/network.md)."""
    from network.infer import DEFAULT_CHECKPOINT

    fills = []
    real_normal = torch.Tensor.normal_
    monkeypatch.setattr(torch.Tensor, "normal_", lambda t, *a, **k: fills.append(1) or real_normal(t, *a, **k))
    loaded, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    assert fills == []  # with the init, every trunc_normal_ call fills by normal_
    monkeypatch.undo()
    torch.manual_seed(0)
    ref = PolarInverseModel(loaded.config)
    ref.load_state_dict(ckpt["model"])
    ref.eval()
    assert torch.equal(torch.nn.init.ones_(torch.zeros(2)), torch.ones(2))  # torch's init is restored
    for (n1, a), (n2, b) in zip(ref.named_buffers(), loaded.named_buffers(), strict=True):
        assert n1 == n2 and torch.equal(a, b), n1
    for (n1, a), (n2, b) in zip(ref.named_parameters(), loaded.named_parameters(), strict=True):
        assert n1 == n2 and torch.equal(a, b), n1


def test_params_sha256_sees_one_changed_element():
    state = {"a": torch.zeros(3), "b": torch.ones(2, 2)}
    before = params_sha256(state)
    state["b"][1, 1] = 1.0 + 2**-20
    assert params_sha256(state) != before and len(before) == 64


def test_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="checkpoint not found"):
        load_checkpoint(tmp_path / "absent.pt")
    path = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(1)}, path)
    with pytest.raises(ValueError, match=r"other\.pt: not a model checkpoint"):
        load_checkpoint(path)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"hello world\n", "not a readable torch checkpoint"),
        (b"", "not a readable torch checkpoint"),
        (b"\x80\x04\x95", "not a readable torch checkpoint"),
    ],
)
def test_non_checkpoint_files_give_one_line(tmp_path, content, message):
    from network.checkpoint import load_checkpoint

    path = tmp_path / "model.pt"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message) as info:
        load_checkpoint(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_a_saved_tensor_is_not_a_checkpoint(tmp_path):
    import torch

    from network.checkpoint import load_checkpoint

    torch.save(torch.zeros(3), tmp_path / "t.pt")
    with pytest.raises(ValueError, match="holds a Tensor, not a dict"):
        load_checkpoint(tmp_path / "t.pt")


def test_a_bf16_model_file_loads_and_predicts_within_tolerance(tmp_path):
    """bf16 weights (half the bytes) load into a float32 model; predictions stay within 1 deg and 0.01."""
    from tests.helpers import make_model, toy_inputs

    model = make_model("toy", seed=3)
    state = {"format": CHECKPOINT_FORMAT, "config": model.config.to_dict(), "inputs": "full",
             "input_scale": "calibrated", "step": 0}  # fmt: skip
    save_checkpoint(tmp_path / "fp32.pt", {**state, "model": model.state_dict()})
    save_checkpoint(tmp_path / "bf16.pt", {**state, "model": {k: v.bfloat16() for k, v in model.state_dict().items()}})
    assert (tmp_path / "bf16.pt").stat().st_size < 0.6 * (tmp_path / "fp32.pt").stat().st_size
    half, _ = load_checkpoint(tmp_path / "bf16.pt")
    assert all(p.dtype == torch.float32 for p in half.parameters())
    maps, mask = toy_inputs()
    with torch.no_grad():
        want, got = model(maps, mask), half(maps, mask)
    inside = mask[:, 0] > 0
    cos = (want["normal"] * got["normal"]).sum(1)[inside].clamp(-1, 1)
    assert float(torch.rad2deg(torch.acos(cos)).max()) < 1.0
    for key in ("albedo", "roughness", "metallic"):
        diff = (want[key] - got[key]).abs().amax(1)[inside]
        assert 0 < float(diff.max()) < 0.01, key  # rounded (not vacuous), within tolerance
