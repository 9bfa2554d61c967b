"""The specs' field checks: what each accepts (as what) and the one-line error naming the field otherwise."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pbrdf.sensor.spec_fields import IDENTITY4, as_float, as_int, as_matrix4, as_vec, check_rigid


class TestAsFloat:
    @pytest.mark.parametrize("value", [1, 2.5, np.float32(0.25), np.int64(-3)])
    def test_numbers_become_float(self, value):
        out = as_float(value, "display.width")
        assert type(out) is float and out == float(value)

    @pytest.mark.parametrize(
        ("value", "reason"),
        [(True, "must be a number"), ("1.0", "must be a number"), (None, "must be a number"),
         (math.nan, "must be finite"), (-math.inf, "must be finite")],
    )  # fmt: skip
    def test_refused_with_the_field(self, value, reason):
        with pytest.raises(ValueError, match=rf"^display\.width {reason}, got"):
            as_float(value, "display.width")


class TestAsInt:
    def test_integral_values(self):
        assert [as_int(v, "n") for v in (3, np.int32(4), 5.0, np.float64(6.0))] == [3, 4, 5, 6]

    @pytest.mark.parametrize("value", [False, 2.5, "3", math.nan])
    def test_refused(self, value):
        with pytest.raises(ValueError, match=r"^display\.resolution\[0\] must be an integer"):
            as_int(value, "display.resolution[0]")


class TestAsVec:
    def test_sequences(self):
        assert as_vec(np.array([1, 2, 3]), 3, "c") == (1.0, 2.0, 3.0)
        assert as_vec((0.5, -1), 2, "size") == (0.5, -1.0)

    @pytest.mark.parametrize(
        ("value", "match"),
        [("abc", r"^center must be a sequence of 3 numbers"), (1.0, r"^center must be a sequence of 3 numbers"),
         ([1.0, 2.0], r"^center must have 3 entries, got 2"), ([1.0, True, 3.0], r"^center\[1\] must be a number")],
    )  # fmt: skip
    def test_refused_naming_the_entry(self, value, match):
        with pytest.raises(ValueError, match=match):
            as_vec(value, 3, "center")


class TestTransforms:
    def test_identity(self):
        np.testing.assert_array_equal(np.array(IDENTITY4), np.eye(4))
        assert as_matrix4(np.eye(4).tolist(), "m") == IDENTITY4

    def test_rotation_plus_translation_is_rigid(self):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_rotvec([0.3, -1.2, 0.7]).as_matrix()  # an independent rotation
        m[:3, 3] = (0.1, -2.0, 5.0)
        check_rigid(as_matrix4(m, "camera.to_world"), "camera.to_world")

    @pytest.mark.parametrize("diag", [(2.0, 1.0, 1.0), (-1.0, 1.0, 1.0), (1.0, 1.0, 1.01)])
    def test_scale_and_mirror_are_not_rigid(self, diag):
        with pytest.raises(ValueError, match=r"^camera\.to_world must be a rigid transform"):
            check_rigid(as_matrix4(np.diag([*diag, 1.0]), "camera.to_world"), "camera.to_world")

    @pytest.mark.parametrize(
        ("value", "match"),
        [(np.eye(3), r"must be a 4x4 matrix, got shape \(3, 3\)"), ([[1, "a"]], r"must be a 4x4 matrix of numbers"),
         (np.full((4, 4), np.nan), "contains NaN or Inf"), (np.ones((4, 4)), r"must be affine \(last row 0 0 0 1\)")],
    )  # fmt: skip
    def test_matrix_refused(self, value, match):
        with pytest.raises(ValueError, match=r"^light\[0\]: to_world " + match):
            as_matrix4(value, "light[0]: to_world")
