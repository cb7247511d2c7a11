"""The task's dimension is data: one wall frame and one reference for a task of 2 or 3 axes (docs/model.md#wall-plane)."""

from __future__ import annotations

import numpy as np
import pytest

from ilcforce.config_load import ConfigError, load_config
from ilcforce.task import Reference, Wall


@pytest.mark.parametrize("wall, n", [(Wall(), 2), (Wall(), 3), (Wall(normal=(0.0, 0.0, 1.0), tangent=(1.0, 1.0, 0.0)), 3),
                                     (Wall(normal=(0.3, -1.0, 0.2), tangent=(0.0, 0.0, 1.0)), 3)])
def test_the_frame_is_a_right_handed_rotation_with_the_normal_last(wall, n):
    R = wall.frame(n)
    assert R.shape == (n, n)
    np.testing.assert_allclose(R @ R.T, np.eye(n), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
    normal = np.asarray(wall.normal or (0.0, 1.0, 0.0)[:n])
    np.testing.assert_allclose(R[-1], normal / np.linalg.norm(normal), atol=1e-15)


def test_a_planar_wall_left_empty_is_the_world_frame():
    assert np.array_equal(Wall().frame(2), np.eye(2))
    assert np.array_equal(Wall(normal=(0.0, 1.0), tangent=(1.0, 0.0)).frame(2), np.eye(2))


@pytest.mark.parametrize("kwargs, words", [({"normal": (1.0, 2.0, 3.0, 4.0)}, "2 or 3 numbers"),
                                           ({"normal": (0.0, 0.0, 0.0)}, "non-zero"),
                                           ({"normal": (0.0, 1.0, 0.0), "tangent": (0.0, 3.0, 0.0)}, "parallel"),
                                           ({"normal": (1.0, 0.0)}, r"tangent \(left out: the x axis\)"),
                                           ({"normal": (0.0, 1.0, 0.0), "tangent": (1.0, 0.0)}, "as many numbers")])
def test_a_bad_wall_is_one_line(kwargs, words):
    with pytest.raises(ValueError, match=words):
        Wall(**kwargs)


def test_tasks_of_other_dimensions_are_refused_by_name():
    with pytest.raises(ValueError, match="2 or 3 axes"):
        Wall().frame(4)
    with pytest.raises(ValueError, match="2 or 3 axes"):
        Reference().sample(np.zeros(3), Wall(), 4)


def test_a_planar_robot_refuses_a_tilted_wall():
    with pytest.raises(ConfigError, match="planar robot's wall is normal to y"):
        load_config(None, overrides={"wall.normal": [1.0, 1.0]})


def test_the_spatial_reference_holds_the_planar_one_on_its_first_and_normal_axes():
    """The same laws in both: x_d on the first axis, F_d (and the pose that makes it) on the normal, v_d between."""
    t = np.linspace(0.0, 2.0, 201)
    wall, ref = Wall(), Reference(v_amplitude=0.05, v_offset=0.01)
    planar, spatial = ref.sample(t, wall, 2), ref.sample(t, wall, 3)
    assert planar.shape == (201, 12) and spatial.shape == (201, 18)
    for block in range(6):
        assert np.array_equal(spatial[:, 3 * block], planar[:, 2 * block])
        assert np.array_equal(spatial[:, 3 * block + 2], planar[:, 2 * block + 1])
    np.testing.assert_allclose(spatial[:, 1], 0.01 + 0.025 * (1.0 - np.cos(np.pi * t)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(spatial[:, 4], 0.025 * np.pi * np.sin(np.pi * t), rtol=0, atol=1e-15)
    assert not spatial[:, 10].any() and not spatial[:, 9].any()  # F_d has no in-plane part


def test_a_small_tangent_is_a_direction_and_a_round_off_tilt_no_tilt():
    """The tangent's test is relative to its own length, and a planar robot takes a frame within round-off of I."""
    R = Wall(normal=(0.0, 1.0, 0.0), tangent=(1e-10, 0.0, 0.0)).frame(3)
    np.testing.assert_array_equal(R[0], (1.0, 0.0, 0.0))
    load_config(None, overrides={"wall.normal": [1e-17, 1.0]})  # no error
