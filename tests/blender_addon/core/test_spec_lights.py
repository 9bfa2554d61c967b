"""Lights and world of a scene spec: JSON round trips through a scene, Cycles unit conversions, validation errors."""

import dataclasses
import math

import numpy as np
import pytest

from blender_addon.core.spec import MaterialSpec, SceneSpec
from blender_addon.core.spec_lights import EnvironmentSpec, LightSpec
from tests.helpers import rigid_pose, rot_x


def test_light_and_environment_specs_round_trip_and_validate(tmp_path):
    lights = (
        LightSpec("key", "area", rigid_pose((0.1, 0.2, 0.3)), (1.0, 0.9, 0.8), 25.0, size=(0.3, 0.2), shape="ellipse",
                  normalize=False),
        LightSpec("bulb", "point", power=5.0),
        LightSpec("cone", "spot", rigid_pose(rot=rot_x(0.3)), power=100.0, spot_angle=0.8, spot_blend=0.2),
        LightSpec("sun", "sun", power=3.0),
    )  # fmt: skip
    env = EnvironmentSpec(strength=0.5, image="sky.exr", to_world=rigid_pose(rot=rot_x(math.pi / 2)))
    spec = SceneSpec(lights=lights, environment=env, materials=(MaterialSpec.diffuse("d", (0.2, 0.3, 0.4)),))
    spec.save(tmp_path / "s.json")
    assert SceneSpec.load(tmp_path / "s.json") == spec
    # Scenes without lights serialise exactly as before this feature.
    assert set(SceneSpec().to_dict()) == {"rig", "objects", "materials", "seed", "metadata"}
    # Unit conversions (Cycles conventions, see LightSpec): L = P / (pi A), I = P / (4 pi).
    assert lights[0].area == pytest.approx(math.pi * 0.3 * 0.2 / 4)
    assert lights[0].radiance()[0] == pytest.approx(25.0 / math.pi)  # not normalized: per square metre
    normalized = dataclasses.replace(lights[0], normalize=True, shape="rectangle")
    assert normalized.radiance()[1] == pytest.approx(25.0 * 0.9 / (math.pi * 0.06))
    assert lights[1].intensity() == pytest.approx((5 / (4 * math.pi),) * 3)
    with pytest.raises(ValueError, match="power must be >= 0"):
        LightSpec("x", "point", power=-1)
    with pytest.raises(ValueError, match="field size is not used by kind 'point'"):
        LightSpec("x", "point", size=(1, 1))
    with pytest.raises(ValueError, match="unknown kind 'laser'"):
        LightSpec("x", "laser")
    with pytest.raises(ValueError, match="rigid transform"):
        LightSpec("x", "point", to_world=np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="pure rotation"):
        EnvironmentSpec(to_world=rigid_pose((0, 0, 1)))
    with pytest.raises(ValueError, match="duplicate light name 'bulb'"):
        SceneSpec(lights=(lights[1], lights[1])).validate()
    with pytest.raises(FileNotFoundError, match="environment image not found"):
        spec.validate()
