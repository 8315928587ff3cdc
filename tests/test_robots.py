"""Robot registry and model building (issue 2)."""

import dataclasses
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


def test_g1_foot_spheres_are_grown_with_the_sole_kept():
    """Menagerie's G1 soles are 5 mm spheres at z = -0.03 in the foot frame; grown to 20 mm, their
    centres go up by 15 mm (z = -0.015), so their lowest point stays at -0.035."""
    source = mujoco.MjModel.from_xml_path(str(resolve_model_dir(ROBOTS["g1"]) / "g1.xml"))
    g1 = build_model("g1")
    m = g1.model
    for foot in g1.robot.foot_bodies:
        before = [g for g in range(source.ngeom) if source.geom_bodyid[g] == source.body(foot).id
                  and source.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE and source.geom_contype[g]]
        after = [g for g in range(m.ngeom) if m.geom_bodyid[g] == m.body(foot).id
                 and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE]
        assert len(before) == len(after) == 4
        assert np.allclose(source.geom_size[before, 0], 0.005)
        assert np.allclose(m.geom_size[after, 0], 0.02)
        assert np.allclose(m.geom_pos[after, :2], source.geom_pos[before, :2])  # same footprint
        assert np.allclose(m.geom_pos[after, 2], -0.015)
        assert np.allclose(m.geom_pos[after, 2] - m.geom_size[after, 0],
                           source.geom_pos[before, 2] - source.geom_size[before, 0])  # the sole stays
    assert ROBOTS["h1"].foot_sphere_radius is None  # H1's capsule feet are left as they are


def test_foot_sphere_radius_is_checked():
    with pytest.raises(ValueError, match=r"foot_sphere_radius must be a positive length in m or None, got -0.01"):
        dataclasses.replace(ROBOTS["g1"], foot_sphere_radius=-0.01)
    with pytest.raises(ValueError, match=r"foot_sphere_radius 0.001 m is below foot body 'left_ankle_roll_link'"):
        build_model(dataclasses.replace(ROBOTS["g1"], foot_sphere_radius=0.001))
    with pytest.raises(ValueError, match=r"foot body 'left_ankle_link' has no colliding sphere"):
        build_model(dataclasses.replace(ROBOTS["h1"], foot_sphere_radius=0.02))
