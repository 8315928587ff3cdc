"""Each reward term of the paper's table on a hand-made state (issue 4)."""

import math

import numpy as np
import pytest

from legoh_rl.envs import rewards
from legoh_rl.envs.rewards import (
    REWARD_FUNCTIONS,
    REWARD_TERMS,
    RewardState,
    compute_rewards,
    reward_weights,
    term,
)


def state(**kw):
    """Two worlds, two joints; every field zero/neutral unless given."""
    n, a = 2, 2
    base = dict(
        lin_vel_w=np.zeros((n, 3)), ang_vel_b=np.zeros((n, 3)), gravity_b=np.tile([0.0, 0.0, -1.0], (n, 1)),
        goal_dir_w=np.tile([1.0, 0.0], (n, 1)), yaw=np.zeros(n), cmd_speed=np.full(n, 0.8),
        q=np.zeros((n, a)), dq=np.zeros((n, a)), dq_prev=np.zeros((n, a)), q_default=np.zeros(a),
        q_limits=np.array([[-1.0, 1.0], [-0.5, 0.5]]), hip_idx=np.array([0]),
        torques=np.zeros((n, a)), torques_prev=np.zeros((n, a)), action=np.zeros((n, a)), action_prev=np.zeros((n, a)),
        foot_force=np.zeros((n, 2, 3)), penalised_force=np.zeros((n, 3, 3)),
        feet_air_time=np.zeros((n, 2)), first_contact=np.zeros((n, 2), bool), feet_at_edge=np.zeros((n, 2), bool),
        terrain_level=np.zeros(n, int), base_height=np.full(n, 1.05), base_height_target=1.05,
        goal_dist=np.full(n, 5.0), reach_radius=0.5, dt=0.02,
    )
    base.update(kw)
    return RewardState(**base)


# The paper's table (appendix, "Rewards' definition and weight"), H1's column, checked by hand.
PAPER_H1 = {
    "tracking_goal_vel": 10.0, "tracking_yaw": 0.5, "lin_vel_z": -2.0, "ang_vel_xy": -1.0, "orientation": -1.0,
    "dof_acc": -3.5e-8, "collision": -10.0, "action_rate": -0.01, "delta_torques": -1.0e-7, "torques": -1.0e-5,
    "hip_pos": -0.5, "dof_error": -0.04, "feet_stumble": -1.0, "feet_edge": -1.0, "feet_air_time": 1.0,
    "base_height": -100.0,
}


def test_every_paper_term_has_a_function():
    assert set(PAPER_H1) | {"pn_distance", "dof_pos_limits"} <= set(REWARD_FUNCTIONS)
    assert set(REWARD_FUNCTIONS) == set(REWARD_TERMS)
    assert all(REWARD_FUNCTIONS[n] is getattr(rewards, f"reward_{n}") for n in REWARD_TERMS)
    extras = {"alive", "termination", "feet_clearance", "feet_slip", "gait_contact", "gait_joint_ref", "feet_in_pit"}
    assert not extras & set(reward_weights())  # the terms beyond the table are off by default


def test_termination_added_after_the_positive_clip():
    s = state(lin_vel_w=np.array([[0, 0, 0.5], [0, 0, 0]]), fell=np.array([True, False]))
    w = {"lin_vel_z": -2.0, "alive": 1.0, "termination": -100.0}
    total, terms = compute_rewards(s, w, only_positive=True)
    # world 0: -0.01 + 0.02 = 0.01 (kept), then -2.0 for the fall; world 1: 0.02
    np.testing.assert_allclose(terms["termination"], [-2.0, 0.0])
    np.testing.assert_allclose(total, [0.01 - 2.0, 0.02])
    w2 = {"lin_vel_z": -20.0}
    total2, _ = compute_rewards(s, w2, only_positive=True)
    np.testing.assert_allclose(total2, [0.0, 0.0])  # -0.2 clipped to 0


def test_tracking_goal_velocity():
    # world 0: 0.4 m/s straight at the goal -> 0.4/0.8; world 1: 2 m/s -> capped at cmd -> ~1
    s = state(lin_vel_w=np.array([[0.4, 0.3, 0.0], [2.0, 0.0, 0.0]]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["tracking_goal_vel"](s), [0.4 / 0.80001, 0.8 / 0.80001], rtol=1e-9)


def test_tracking_yaw_wraps():
    # goal straight ahead (0 rad); world 0 faces 0.5 rad off; world 1 faces pi - 0.1 past it: error wraps
    s = state(goal_dir_w=np.array([[1.0, 0.0], [-1.0, 0.0]]), yaw=np.array([0.5, -math.pi + 0.1 - 0.2]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["tracking_yaw"](s), [math.exp(-0.5), math.exp(-0.1)], rtol=1e-9)


def test_base_motion_penalties():
    s = state(lin_vel_w=np.array([[0, 0, 0.5], [0, 0, -2.0]]), ang_vel_b=np.array([[1.0, 2.0, 9.0], [0, 0, 0]]),
              gravity_b=np.array([[0.6, 0.0, -0.8], [0.0, 0.0, -1.0]]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["lin_vel_z"](s), [0.25, 4.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["ang_vel_xy"](s), [5.0, 0.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["orientation"](s), [0.36, 0.0])


def test_joint_and_torque_penalties():
    s = state(dq=np.array([[1.0, 0.0], [0.0, 0.0]]), dq_prev=np.array([[0.0, 0.2], [0.0, 0.0]]),
              torques=np.array([[10.0, -20.0], [0, 0]]), torques_prev=np.array([[7.0, -20.0], [0, 1.0]]),
              action=np.array([[0.3, 0.4], [0, 0]]), q=np.array([[0.2, -0.3], [1.5, 0.7]]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["dof_acc"](s), [(1 / 0.02) ** 2 + (0.2 / 0.02) ** 2, 0.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["torques"](s), [500.0, 0.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["delta_torques"](s), [9.0, 1.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["action_rate"](s), [0.5, 0.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["dof_error"](s), [0.13, 2.74])
    np.testing.assert_allclose(REWARD_FUNCTIONS["hip_pos"](s), [0.04, 2.25])  # joint 0 only
    # limits [-1, 1] and [-0.5, 0.5]: world 1 is 0.5 past on joint 0 and 0.2 past on joint 1
    np.testing.assert_allclose(REWARD_FUNCTIONS["dof_pos_limits"](s), [0.0, 0.7])


def test_contact_terms():
    pen = np.zeros((2, 3, 3))
    pen[0, 0] = [0.0, 0.0, 0.05]  # below the 0.1 N threshold
    pen[0, 1] = [0.2, 0.0, 0.0]
    pen[0, 2] = [0.0, 5.0, 0.0]
    feet = np.zeros((2, 2, 3))
    feet[0, 0] = [50.0, 0.0, 10.0]  # horizontal 50 > 4 x 10: stumble
    feet[1, 0] = [30.0, 0.0, 10.0]  # 30 < 40: no stumble
    s = state(penalised_force=pen, foot_force=feet)
    np.testing.assert_allclose(REWARD_FUNCTIONS["collision"](s), [2.0, 0.0])
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_stumble"](s), [1.0, 0.0])


def test_feet_edge_only_above_level_3():
    s = state(feet_at_edge=np.array([[True, True], [True, False]]), terrain_level=np.array([3, 4]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_edge"](s), [0.0, 1.0])


def test_feet_edge_gate_can_start_lower():
    s = state(feet_at_edge=np.array([[True, True], [True, False], [False, False]]),
              terrain_level=np.array([0, 1, 4]), feet_edge_from_level=1)
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_edge"](s), [0.0, 1.0, 0.0])
    s.feet_edge_from_level = 0
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_edge"](s), [2.0, 1.0, 0.0])


def test_feet_air_time():
    s = state(feet_air_time=np.array([[0.8, 0.3], [0.8, 0.0]]), first_contact=np.array([[True, True], [False, False]]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_air_time"](s), [0.3 - 0.2, 0.0])


def test_base_height_and_point_navigation():
    s = state(base_height=np.array([0.95, 1.05]), goal_dist=np.array([0.3, 4.0]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["base_height"](s), [0.01, 0.0], atol=1e-12)
    np.testing.assert_allclose(REWARD_FUNCTIONS["pn_distance"](s), [1.0, -3.0])


def test_base_height_cap_counts_only_that_much_of_a_pelvis_above_its_target():
    """A pelvis 1 m over a pit floor reads a 1 m error; the cap counts 0.1 m of it, a pelvis
    below its target in full, and no cap the whole error (numpy and torch alike)."""
    import torch

    heights = np.array([2.05, 0.85, 1.10, 1.05])
    s = state(base_height=heights, base_height_cap=0.1, goal_dist=np.full(4, 5.0))
    np.testing.assert_allclose(REWARD_FUNCTIONS["base_height"](s), [0.01, 0.04, 0.0025, 0.0], atol=1e-12)
    uncapped = state(base_height=heights, goal_dist=np.full(4, 5.0))
    np.testing.assert_allclose(REWARD_FUNCTIONS["base_height"](uncapped), [1.0, 0.04, 0.0025, 0.0], atol=1e-12)
    on_torch = state(base_height=torch.tensor(heights), base_height_cap=0.1, goal_dist=torch.full((4,), 5.0),
                     q=torch.zeros(4, 2))
    torch.testing.assert_close(REWARD_FUNCTIONS["base_height"](on_torch),
                               torch.tensor([0.01, 0.04, 0.0025, 0.0], dtype=torch.float64))


def test_weights_per_robot_and_dt_scaling():
    h1 = reward_weights("h1")
    g1 = reward_weights("g1", student=True)
    assert h1 == PAPER_H1 and list(h1) == list(PAPER_H1)  # the order the terms are summed in
    # G1's column differs in three rows; dof_pos_limits is on for G1 only, pn_distance for students only
    assert g1 == {**PAPER_H1, "feet_air_time": 0.5, "base_height": -35.0, "pn_distance": 1.0, "dof_pos_limits": -5.0}
    assert reward_weights("G1", student=True) == g1 and reward_weights() == h1
    s = state(lin_vel_w=np.array([[0, 0, 0.5], [0, 0, 0]]))
    total, terms = compute_rewards(s, {"lin_vel_z": -2.0, "tracking_yaw": 0.5})
    np.testing.assert_allclose(terms["lin_vel_z"], [-2.0 * 0.25 * 0.02, 0.0])
    np.testing.assert_allclose(total, terms["lin_vel_z"] + 0.5 * 0.02)


def test_unknown_override_lists_terms():
    with pytest.raises(ValueError, match=r"unknown reward term 'speed'.*tracking_yaw"):
        reward_weights(overrides={"speed": 1.0})
    with pytest.raises(ValueError, match=r"unknown robot 'go2'.*\['g1', 'h1'\]"):
        reward_weights("go2")


def test_overrides_come_last_and_zero_drops_a_term():
    w = reward_weights("g1", {"alive": 2.0, "termination": -50.0, "base_height": -10, "feet_edge": 0.0})
    assert w["alive"] == 2.0 and w["termination"] == -50.0 and w["base_height"] == -10.0
    assert "feet_edge" not in w and "pn_distance" not in w
    assert list(w)[-2:] == ["alive", "termination"]  # the registry's order, not the overrides'


def _reward_probe(s):
    """A term for the registration tests (never registered)."""
    return s.q[:, 0]


@pytest.mark.parametrize(
    "decorate, match",
    [
        (lambda fn: term()(fn), r"reward term 'probe' has no weight: write @term\(weight=\.\.\.\)"),
        (lambda fn: term(fn), r"reward term 'probe' has no weight"),
        (lambda fn: term(weight="1")(fn), r"reward term 'probe': weight must be a finite number.*'1'"),
        (lambda fn: term(weight=float("nan"))(fn), r"reward term 'probe': weight must be a finite number"),
        (lambda fn: term(weight=1.0, per_robot={"go2": 0.5})(fn),
         r"reward term 'probe': per_robot names unknown robots \['go2'\]; known robots: \['g1', 'h1'\]"),
        (lambda fn: term(weight=1.0, per_robot={"g1": None})(fn), r"reward term 'probe': per_robot\['g1'\] must be"),
    ],
)
def test_a_term_without_a_weight_or_with_an_unknown_robot_is_refused(decorate, match):
    def reward_probe(s):
        return _reward_probe(s)

    with pytest.raises(ValueError, match=match):
        decorate(reward_probe)
    assert "probe" not in REWARD_TERMS


def test_a_term_is_registered_once_and_by_its_name():
    with pytest.raises(ValueError, match=r"reward term 'tracking_yaw' is already registered \(RewardTerm\(name='tracking_yaw'"):
        term(weight=1.0)(rewards.reward_tracking_yaw)
    with pytest.raises(ValueError, match=r"function '_reward_probe' must be named reward_<name>"):
        term(weight=1.0)(_reward_probe)


def test_feet_clearance_wants_moving_feet_lifted():
    # world 0: left foot moving at 4 m/s on the ground (lift 0), right foot still; world 1: left foot
    # moving at 1 m/s lifted exactly the swing height, right foot moving at 0.25 m/s lifted 0.3 m
    s = state(foot_lift=np.array([[0.0, 0.2], [0.1, 0.3]]),
              foot_vel_xy=np.array([[[0.0, 4.0], [0.0, 0.0]], [[0.6, 0.8], [0.25, 0.0]]]), swing_height=0.1)
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_clearance"](s), [0.01 * 2.0, 0.04 * 0.5])


def test_feet_slip_counts_sliding_feet_in_contact():
    # world 0: left foot on the ground sliding at 0.5 m/s, right foot in the air at 2 m/s (ignored)
    s = state(feet_contact=np.array([[True, False], [True, True]]),
              foot_vel_xy=np.array([[[0.3, 0.4], [2.0, 0.0]], [[0.0, 0.0], [0.0, -0.1]]]))
    np.testing.assert_allclose(REWARD_FUNCTIONS["feet_slip"](s), [0.5, 0.1])


def test_gait_terms_name_missing_fields():
    with pytest.raises(ValueError, match="foot_lift"):
        REWARD_FUNCTIONS["feet_clearance"](state(foot_vel_xy=np.zeros((2, 2, 2))))
    with pytest.raises(ValueError, match="feet_contact"):
        REWARD_FUNCTIONS["feet_slip"](state(foot_vel_xy=np.zeros((2, 2, 2))))


def test_gait_contact_counts_feet_that_follow_the_clock():
    # world 0 at phase 0.25 (left stance, right swing); world 1 at phase 0.52 (double stance)
    phase = np.array([0.25, 0.52])
    for contact, expected in (([[True, False], [True, True]], [2.0, 2.0]),
                              ([[True, True], [False, True]], [1.0, 1.0]),
                              ([[False, True], [False, False]], [0.0, 0.0])):
        s = state(feet_contact=np.array(contact), gait_phase=phase, gait_stance=0.55)
        np.testing.assert_array_equal(REWARD_FUNCTIONS["gait_contact"](s), expected)
    with pytest.raises(ValueError, match="gait_phase"):
        REWARD_FUNCTIONS["gait_contact"](state(feet_contact=np.ones((2, 2), bool)))


def test_gait_joint_ref_rewards_joints_on_the_clocks_reference():
    ref = np.array([[0.0, 0.0], [0.3, -0.4]])
    # world 0 on its reference (d = 0 -> 1); world 1 off by (0.3, 0.4): d = 0.5
    s = state(q=np.array([[0.0, 0.0], [0.0, 0.0]]), gait_ref_q=ref)
    np.testing.assert_allclose(REWARD_FUNCTIONS["gait_joint_ref"](s), [1.0, math.exp(-1.0) - 0.1])
    far = state(q=np.array([[2.0, 0.0], [0.0, 0.0]]), gait_ref_q=np.zeros((2, 2)))
    assert REWARD_FUNCTIONS["gait_joint_ref"](far)[0] == pytest.approx(math.exp(-4.0) - 0.1)  # the clamp at 0.5
    with pytest.raises(ValueError, match="gait_ref_q"):
        REWARD_FUNCTIONS["gait_joint_ref"](state())
