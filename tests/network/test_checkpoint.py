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
