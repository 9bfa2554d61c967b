import json
import math

import numpy as np
import pytest

from pbrdf.io.strict_json import dumps_strict, loads_strict, to_strict


def test_non_finite_becomes_null_and_numpy_becomes_python():
    obj = {"a": math.nan, "b": [np.float32(np.inf), -math.inf, 1.5], "c": np.arange(3), "d": (np.int64(2),)}
    text = dumps_strict(obj)
    assert loads_strict(text) == {"a": None, "b": [None, None, 1.5], "c": [0, 1, 2], "d": [2]}
    assert "NaN" not in text and "Infinity" not in text
    assert to_strict({"x": np.float64(2.0)}) == {"x": 2.0}


def test_strict_parser_refuses_what_json_accepts():
    for bad in ('{"x": NaN}', "[Infinity]", "-Infinity"):
        json.loads(bad)  # Python's parser accepts it ...
        with pytest.raises(ValueError, match="not strict JSON"):
            loads_strict(bad)  # ... a strict one does not
