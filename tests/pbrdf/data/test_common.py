"""pbrdf.io.strict_json.read_json_object: the one JSON reader turns every parse failure into one line."""

import pytest

from pbrdf.io.strict_json import read_json_object


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[" * 100_000 + "]" * 100_000, r"invalid JSON \(nested too deeply\)"),  # was a RecursionError traceback
        ('{"format": "x", "n": ' + "9" * 5000 + "}", r"invalid JSON \(Exceeds the limit \(4300 digits\)"),
        ('{"format": ', r"invalid JSON \(Expecting value"),
        ("[1]", "expected a JSON object; got list"),
        ('{"format": "' + "y" * 500 + '"}', r"unsupported format 'yyyy.*\.\.\.; expected 'x'$"),
    ],
    ids=["nested 100000 levels", "5000 digits", "truncated", "not an object", "long format"],
)
def test_bad_json_is_one_line_naming_the_file(tmp_path, text, match):
    path = tmp_path / "s.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        read_json_object(path, "x")
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message and len(message) < 300


def test_not_utf8(tmp_path):
    path = tmp_path / "s.json"
    path.write_bytes(b'{"format": "\xff"}')
    with pytest.raises(ValueError, match=f"{path}: invalid JSON"):
        read_json_object(path, "x")
