"""Robot registry and model building (issue 2)."""

import math

import mujoco
import numpy as np
import pytest

from legoh_rl.envs.robots import ROBOTS, build_model, get_robot_spec, resolve_model_dir

H1_JOINTS = [
    "left_hip_yaw", "left_hip_roll", "left_hip_pitch", "left_knee", "left_ankle",
    "right_hip_yaw", "right_hip_roll", "right_hip_pitch", "right_knee", "right_ankle",
]


@pytest.fixture(scope="module", params=["h1", "g1"])
def built(request):
    return build_model(request.param)


def test_unknown_robot_lists_known_ones():
    with pytest.raises(ValueError, match=r"unknown robot 'atlas'.*\['g1', 'h1'\]"):
        get_robot_spec("atlas")


def test_h1_has_no_ankle_roll_to_freeze():
    with pytest.raises(ValueError, match="no ankle-roll"):
        get_robot_spec("h1", freeze_ankle_roll=True)


def test_missing_model_folder_says_where_and_how(tmp_path, monkeypatch):
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"unitree_h1.*MENAGERIE_ROOT="):
        resolve_model_dir(ROBOTS["h1"])


def test_joint_order_and_action_sizes():
    h1 = build_model("h1")
    assert list(h1.robot.leg_joints) == H1_JOINTS
    assert h1.model.nu == 10 and h1.model.nv == 16  # 6 free + 10 legs: upper body frozen
    g1 = build_model("g1")
    assert g1.model.nu == 12 and g1.model.nv == 18
    assert [j.split("_joint")[0] for j in g1.robot.leg_joints[:6]] == [
        "left_hip_pitch", "left_hip_roll", "left_hip_yaw", "left_knee", "left_ankle_pitch", "left_ankle_roll",
    ]
    g1_10 = build_model(get_robot_spec("g1", freeze_ankle_roll=True))
    assert g1_10.model.nu == 10 and g1_10.model.nv == 16
    assert not any("ankle_roll" in j for j in g1_10.robot.leg_joints)
    # ctrl columns follow the action order
    for i, name in enumerate(H1_JOINTS):
        assert h1.model.actuator(int(h1.actuator_ids[i])).name == name
        assert h1.model.joint(name).qposadr[0] == h1.qpos_adr[i]


def test_actuators_are_pd_with_unitree_gains_and_torque_limits(built):
    m, r = built.model, built.robot
    for i, a in enumerate(built.actuator_ids):
        assert m.actuator_gainprm[a, 0] == pytest.approx(r.kp[i])
        assert m.actuator_biasprm[a, 1] == pytest.approx(-r.kp[i])
        assert m.actuator_biasprm[a, 2] == pytest.approx(-r.kd[i])
        assert m.actuator_forcelimited[a] == 1
        np.testing.assert_allclose(m.actuator_forcerange[a], [-r.torque_limits[i], r.torque_limits[i]])


def test_head_camera_looks_forward_and_down(built):
    m = built.model
    d = mujoco.MjData(m)
    d.qpos[:] = built.default_qpos
    mujoco.mj_forward(m, d)
    cam = built.camera_id
    axis = -d.cam_xmat[cam].reshape(3, 3)[:, 2]  # a MuJoCo camera looks along its -z
    pitch = math.degrees(math.atan2(-axis[2], axis[0]))
    assert pitch == pytest.approx(built.robot.camera_pitch_deg, abs=1e-6)
    assert abs(axis[1]) < 1e-9
    assert m.cam_fovy[cam] == pytest.approx(built.robot.camera_fovy_deg)
    # eye level: above the pelvis, below the top of the head
    assert d.cam_xpos[cam, 2] > built.robot.spawn_height + 0.35


def test_bad_timestep_refused():
    with pytest.raises(ValueError, match="timestep"):
        build_model("h1", timestep=0.0)
