"""headless/evaluate.py: the --input flag and one-line errors.

The evaluation itself and the CLI on rendered splits are tested in tests/network/test_evaluation.py.
"""

from headless import evaluate


def test_missing_dataset_is_one_error_line(tmp_path, capsys):
    code = evaluate.main(["--checkpoint", str(tmp_path / "m.pt"), "--input", str(tmp_path / "missing"), "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and lines == [f"error: {tmp_path / 'missing'}: dataset folder not found"], lines


def test_bad_flags_and_a_missing_checkpoint_are_one_error_line(tmp_path, capsys):
    (tmp_path / "data").mkdir()
    for args, msg in [
        (["--input", str(tmp_path / "data"), "--limit", "0"], "error: --limit must be >= 1, got 0"),
        (["--input", str(tmp_path / "data"), "--jobs", "0"], "error: --jobs must be >= 1, got 0"),
        (["--input", str(tmp_path / "data"), "--checkpoint", str(tmp_path / "no.pt")],
         f"error: {tmp_path / 'no.pt'}: checkpoint not found"),
    ]:  # fmt: skip
        assert evaluate.main([*args, "--quiet"]) == 2, args
        assert capsys.readouterr().err.strip().splitlines() == [msg]


def test_split_on_a_missing_gpu_is_one_error_line(tmp_path, capsys):
    import torch

    if torch.cuda.is_available():
        return
    code = evaluate.main(["--split", "test", "--input", str(tmp_path), "--device", "cuda", "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    expected = "error: device cuda: CUDA is not available on this machine (use --device cpu or auto)"
    assert code == 2 and lines == [expected]
