"""The body state the env starts each step from: the native kernel against the numpy reference,
and both against hand-made states."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.body_state import FLAG_FIELDS, FLOAT_FIELDS, BodyStateReader
from legoh_rl.envs.device_terrain import DeviceTerrain
from legoh_rl.envs.native.build import load_library
from legoh_rl.envs.trail_source import trails_for

needs_native = pytest.mark.skipif(load_library() is None, reason="native kernels unavailable")


@pytest.fixture(scope="module")
def env():
    trails = trails_for(("ditch",), variants=1, seed=0)  # edges (feet-edge) and uneven ground
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=8, mode="oracle", categories=("ditch",), levels=(2, 3),
                                    num_threads=1, seed=0), trails=trails)
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(40):  # walking, falling, resetting: contacts on and off
        td["action"] = 0.6 * torch.randn(8, env.A, generator=gen)
        _, td = env.step_and_maybe_reset(td)
    return env


def assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].shape == b[key].shape and a[key].dtype == b[key].dtype, key
        np.testing.assert_allclose(a[key], b[key], rtol=0, atol=1e-9, err_msg=key)


@needs_native
@pytest.mark.parametrize("ids", [None, np.array([5, 0, 7]), np.array([], dtype=np.int64)])
def test_native_matches_numpy(env, ids):
    assert env.step_state.body.native
    native, ref = env.step_state.body.read(ids, env.end), env.step_state.body.read_python(ids, env.end)
    assert set(native) == {name for name, _ in FLOAT_FIELDS + FLAG_FIELDS}
    assert_same(native, ref)
    n = 8 if ids is None else ids.size
    assert native["rot"].shape == (n, 3, 3) and native["pen_force"].shape == (n, env.step_state.body.P, 3)
    assert native["contact"].dtype == bool


def hand_made_worlds(env, n=2):
    """Writable stand-ins for the batch's arrays (the live ones are partly read-only)."""
    w = env.worlds
    return SimpleNamespace(num_worlds=n, **{k: np.zeros((n, *getattr(w, k).shape[1:]))
                                           for k in ("qpos", "qvel", "sensordata", "xpos", "actuator_force")})


@needs_native
def test_hand_made_state(env):
    """A world put at a known pose, velocity, foot positions and sensor forces reads back the
    values computed by hand (native and numpy alike)."""
    w, b, r = hand_made_worlds(env), env.built, 1
    reader = BodyStateReader(w, b, env.trails, env.robot.foot_rest_height)
    x, y, z, yaw = 10.3, 2.1, 1.4, 0.5
    w.qpos[:, 3] = 1.0
    w.qpos[r, :3] = x, y, z
    w.qpos[r, 3:7] = math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)  # pure heading
    w.qpos[r, b.qpos_adr] = np.linspace(-0.5, 0.5, b.qpos_adr.size)
    w.qvel[r, :6] = 1.0, 0.0, 0.2, 0.0, 0.0, 0.3
    w.actuator_force[r, b.actuator_ids] = np.arange(b.actuator_ids.size)
    edge, (ex0, ey0), res = env.trails.edge_grid
    ei, ej = np.argwhere(edge)[0]
    ni, nj = np.argwhere(~edge)[len(np.argwhere(~edge)) // 2]
    feet = b.foot_body_ids
    # foot 0 near an edge sample (0.4 cell off: rounds to it), foot 1 near a plain one
    w.xpos[r, feet[0]] = ex0 + (ei + 0.4) * res, ey0 + ej * res, 0.3
    w.xpos[r, feet[1]] = ex0 + ni * res, ey0 + (nj - 0.4) * res, 0.5
    fcol = reader.foot_force_cols
    w.sensordata[r, fcol[0]] = 0.6, 0.6, 0.6  # |F| = 1.04 N > 1 N: contact
    w.sensordata[r, fcol[1]] = 0.0, 0.0, 0.9  # 0.9 N: no contact
    end = np.zeros((2, 3))
    end[r] = 13.3, 6.1, 0.0
    assert reader.native
    for s in (reader.read(np.array([r]), end), reader.read_python(np.array([r]), end)):
        np.testing.assert_allclose(s["yaw"], [yaw], atol=1e-12)
        np.testing.assert_allclose(s["roll"], [0.0], atol=1e-12)
        np.testing.assert_allclose(s["pitch"], [0.0], atol=1e-12)
        np.testing.assert_allclose(s["gravity_b"], [[0, 0, -1]], atol=1e-12)
        # base frame: x forward at heading 0.5 rad
        np.testing.assert_allclose(s["lin_vel_b"], [[math.cos(yaw), -math.sin(yaw), 0.2]], atol=1e-12)
        np.testing.assert_allclose(s["ang_vel_b"], [[0, 0, 0.3]], atol=1e-12)
        np.testing.assert_allclose(s["goal_vec"], [[3.0, 4.0]], atol=1e-12)
        np.testing.assert_allclose(s["goal_dist"], [5.0], atol=1e-12)
        ground = env.trails.height_at(np.array([[x, y]]))
        np.testing.assert_allclose(s["base_height"], z - ground, atol=1e-12)
        feet_xy = w.xpos[r, feet, :2]
        lift = w.xpos[r, feet, 2] - env.trails.height_at(feet_xy) - env.robot.foot_rest_height
        np.testing.assert_allclose(s["foot_lift"][0], lift, atol=1e-12)
        assert s["contact"].tolist() == [[True, False]]
        assert s["foot_on_edge"].tolist() == [[True, False]]
        np.testing.assert_array_equal(s["q"][0], np.linspace(-0.5, 0.5, b.qpos_adr.size))
        np.testing.assert_array_equal(s["torques"][0], np.arange(b.actuator_ids.size))
        np.testing.assert_allclose(s["foot_force"][0, 0], [0.6, 0.6, 0.6])


@needs_native
def test_outputs_are_fresh_and_bad_rows_refused(env):
    s = env.step_state.body.read(None, env.end)
    s["pos"][:] = 1e9
    assert not np.allclose(env.step_state.body.read(None, env.end)["pos"], 1e9)
    with pytest.raises(ValueError, match=r"world ids must lie in \[0, 8\), got \[8\]"):
        env.step_state.body.read(np.array([8]), env.end)
    with pytest.raises(ValueError, match=r"end must be a C-contiguous float64 \(8, 3\) array"):
        env.step_state.body.read(None, env.end[:4])


@needs_native
def test_non_finite_state_reads_without_crashing(env):
    """A NaN foot position (a diverging world, before the env resets it) must not index outside
    the edge mask: the foot reads 'not on an edge'."""
    w = hand_made_worlds(env)
    w.qpos[:, 3] = 1.0
    w.xpos[1, env.built.foot_body_ids] = np.nan
    w.sensordata[1, env.step_state.body.foot_force_cols[:, 2]] = 10.0  # in contact
    s = BodyStateReader(w, env.built, env.trails, env.robot.foot_rest_height).read(None, np.zeros((2, 3)))
    assert s["contact"][1].all() and not s["foot_on_edge"][1].any()
    assert np.isnan(s["foot_lift"][1]).all() and np.isfinite(s["foot_lift"][0]).all()


def test_numpy_fallback_when_native_is_off(env, monkeypatch):
    monkeypatch.setenv("LEGOH_RL_NATIVE", "0")
    assert not env.step_state.body.native
    assert_same(env.step_state.body.read(None, env.end), env.step_state.body.read_python(None, env.end))


def test_the_python_body_state_reads_tensors_as_it_reads_numpy(env):
    """One Python body state for both backends: on tensors of the simulation's arrays and the
    terrain's grids as tensors (what a device-resident step reads) it gives the host's values,
    in the tensors' dtype, rows in the order asked."""
    host = env.step_state.body
    views = {name: torch.as_tensor(np.array(a)) for name, a in host.arrays.items()}
    reader = BodyStateReader(views, env.built, DeviceTerrain(env.trails, "cpu"), env.robot.foot_rest_height)
    assert not reader.native  # the native kernel reads the host's float64 arrays only
    ids = np.array([5, 0, 7])
    got, ref = reader.read(torch.as_tensor(ids), torch.as_tensor(env.end)), host.read_python(ids, env.end)
    assert got.keys() == ref.keys() and got["contact"].any()
    for key, value in ref.items():
        assert got[key].shape == value.shape and got[key].dtype == torch.from_numpy(value).dtype, key
        np.testing.assert_allclose(got[key].numpy(), value, rtol=0, atol=1e-4, err_msg=key)  # float32 surface
