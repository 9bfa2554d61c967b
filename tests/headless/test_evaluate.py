"""headless/evaluate.py: the --input flag and one-line errors.

Evaluation itself and the CLI run on a trained checkpoint are tested with network.evaluate.
"""

from headless import evaluate


def test_missing_dataset_is_one_error_line(tmp_path, capsys):
    code = evaluate.main(["--checkpoint", str(tmp_path / "m.pt"), "--input", str(tmp_path / "missing"), "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), lines


def test_checkpoint_variants():
    from pathlib import Path

    import pytest

    assert evaluate._checkpoints(["a.pt"]) == Path("a.pt")
    assert evaluate._checkpoints(["full=a.pt", "white=b.pt"]) == {"full": Path("a.pt"), "white": Path("b.pt")}
    with pytest.raises(ValueError, match="VARIANT=PATH"):
        evaluate._checkpoints(["full=a.pt", "b.pt"])
    with pytest.raises(ValueError, match="given twice"):
        evaluate._checkpoints(["full=a.pt", "full=b.pt"])


def test_split_on_a_missing_gpu_is_one_error_line(tmp_path, capsys):
    import torch

    if torch.cuda.is_available():
        return
    code = evaluate.main(["--split", "test", "--input", str(tmp_path), "--device", "cuda", "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    expected = "error: device cuda: CUDA is not available on this machine (use --device cpu or auto)"
    assert code == 2 and lines == [expected]
