"""The gait clock's stance pattern and swing reference (legoh_rl.envs.gait)."""

import math

import numpy as np
import pytest

from legoh_rl.envs.gait import stance_mask, swing_joints, swing_reference
from legoh_rl.envs.robots import get_robot_spec


def test_stance_mask_puts_the_legs_half_a_period_apart():
    phase = np.array([0.0, 0.25, 0.52, 0.6, 0.75, 0.99])
    # left leg: stance while phase < 0.55; right leg: while (phase + 0.5) mod 1 < 0.55
    np.testing.assert_array_equal(
        stance_mask(phase, 0.55),
        [[True, True], [True, False], [True, True], [False, True], [False, True], [False, True]],
    )


def test_swing_joints_of_both_robots():
    h1 = get_robot_spec("h1").leg_joints
    np.testing.assert_array_equal(swing_joints(h1), [[2, 3, 4], [7, 8, 9]])
    g1 = get_robot_spec("g1").leg_joints  # ankle pitch, not ankle roll
    np.testing.assert_array_equal(swing_joints(g1), [[0, 3, 4], [6, 9, 10]])
    with pytest.raises(ValueError, match="need exactly one right knee joint"):
        swing_joints(("left_hip_pitch", "left_knee", "left_ankle", "right_hip_pitch", "right_ankle"))


def test_swing_reference_folds_the_leg_the_clock_has_in_swing():
    joints = swing_joints(get_robot_spec("h1").leg_joints)
    ref = swing_reference(np.array([0.25, 0.75, 0.125, 0.0, 0.51]), joints, 10, 0.2)
    # phase 0.25: sin = 1, the right leg swings at full amplitude: hip -0.2, knee +0.4, ankle -0.2
    np.testing.assert_allclose(ref[0], [0, 0, 0, 0, 0, 0, 0, -0.2, 0.4, -0.2], atol=1e-12)
    # phase 0.75: sin = -1, the left leg
    np.testing.assert_allclose(ref[1], [0, 0, -0.2, 0.4, -0.2, 0, 0, 0, 0, 0], atol=1e-12)
    # phase 0.125: sin = 0.707, the right leg at 0.707 of the amplitude
    a = 0.2 * math.sin(math.pi / 4)
    np.testing.assert_allclose(ref[2, 7:], [-a, 2 * a, -a])
    # double support near phases 0 and 0.5 (|sin| < 0.1): the default pose
    np.testing.assert_array_equal(ref[3:], 0.0)
