"""headless/expand_pbrdf.py: the --input flag and one-line errors.

The expansion itself is tested with pbrdf.expansion.run.
"""

from headless import expand_pbrdf


def test_input_must_be_a_folder(tmp_path, capsys):
    code = expand_pbrdf.main(["--out", str(tmp_path / "o"), "--input", str(tmp_path / "none"), "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and lines == [f"error: --input {tmp_path / 'none'}: not a folder"]


def test_count_must_be_positive(tmp_path, capsys):
    assert expand_pbrdf.main(["--out", str(tmp_path / "o"), "--count", "0"]) == 2
    assert "--count must be >= 1" in capsys.readouterr().err


def test_components_must_be_positive(tmp_path, capsys):
    code = expand_pbrdf.main(["--out", str(tmp_path / "o"), "--components", "0", "0", "--count", "1", "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and lines == ["error: --components must be two integers >= 1 (K_I K_P), got 0 0"]
    assert not (tmp_path / "o").exists()  # nothing written
