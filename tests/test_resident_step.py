"""The device-resident step (``cfg.resident``: the step state on the device) against the host step,
both on MuJoCo Warp's CPU device.

The two paths step the same simulation: the resident one reads Warp's arrays as tensors and
computes observations, rewards and metrics there; the host one copies the state to numpy. The PD
targets are rounded to float32 from the same float64 values in both, so the physics stays
identical and the outputs differ by float32 rounding only (the host computes in float64): within
1e-5 (values of order 1 to 10, float32's ulp there ~1e-7 to 1e-6), with identical flags, episode ends, curriculum updates and resets,
over episodes that end and restart with domain randomisation (pushes included) on.
"""

import numpy as np
import pytest
import torch
from torchrl.envs import check_env_specs

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.device_terrain import DeviceTerrain, MaskGrid
from legoh_rl.envs.hiking import HikingEnv
from legoh_rl.envs.trail_source import trails_for
from legoh_rl.envs.warp_physics import WarpWorlds
from legoh_rl.training.config_store import env_config

N = 4
BASE = dict(robot="h1", num_envs=N, num_threads=1, physics="warp", seed=3)


def pair(**kw):
    """(host, resident) Warp envs of the same config."""
    return HikingEnv(HikingEnvConfig(**BASE, **kw)), HikingEnv(HikingEnvConfig(**BASE, resident=True, **kw))


def spy_curriculum(env, calls):
    update = env.curriculum.update

    def record(ids, progress, expected, reached, rng):
        calls.append((np.asarray(ids).tolist(), np.asarray(progress), np.asarray(reached).tolist()))
        return update(ids, progress, expected, reached, rng)

    env.curriculum.update = record


def rollout_both(host, res, steps, scale, seed=0):
    """Step both envs with the same random actions (torchrl's step_and_maybe_reset); yield the
    two step outputs of each step."""
    th, tr = host.reset(), res.reset()
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        a = scale * torch.randn(N, host.A, generator=g)
        out_h, th = host.step_and_maybe_reset(th.set("action", a))
        out_r, tr = res.step_and_maybe_reset(tr.set("action", a))
        yield out_h["next"], out_r["next"]


def assert_same_outputs(nh, nr, obs_atol=1e-5):
    for key in nh.keys(True, True):
        a, b = nh[key], nr[key]
        assert a.shape == b.shape and a.dtype == b.dtype, key
        if a.dtype == torch.bool or a.dtype == torch.int64:
            assert torch.equal(a, b), key
        else:
            assert torch.allclose(a, b, atol=obs_atol, rtol=1e-5, equal_nan=True), (key, (a - b).abs().max())


def test_oracle_resident_step_equals_the_host_step_over_resets_and_pushes():
    host, res = pair(mode="oracle")
    assert host.step_state.device is None and res.step_state.device is not None and res.worlds.resident
    calls_h, calls_r = [], []
    spy_curriculum(host, calls_h)
    spy_curriculum(res, calls_r)
    ends = 0
    for nh, nr in rollout_both(host, res, 120, scale=1.5):
        assert_same_outputs(nh, nr)
        ends += int(nh["done"].sum())
    assert ends >= 4  # episodes ended (falls) and their worlds restarted
    assert [c[0] for c in calls_h] == [c[0] for c in calls_r] and len(calls_h) >= 3
    for (_, ph, sh), (_, pr, sr) in zip(calls_h, calls_r, strict=True):
        assert np.allclose(ph, pr, atol=1e-5) and sh == sr
    assert np.array_equal(host.curriculum.levels, res.curriculum.levels)
    assert host.global_steps == res.global_steps and host.diverged_total == res.diverged_total
    assert np.allclose(host.worlds.qpos, torch.as_tensor(res.worlds.views["qpos"]).double().numpy(), atol=1e-6)


def test_student_resident_step_with_depth_gait_clock_and_pits_equals_the_host_step():
    """Student mode: the depth image (host march, sent to the device), the gait clock's proprio
    columns, terms and feed-forward targets, and the feet_in_pit term read on the device's pit mask."""
    kw = dict(mode="student", gait_period=0.8, gait_feedforward=0.5,
              reward_overrides={"feet_in_pit": -1.0, "gait_contact": 0.5, "gait_joint_ref": 0.5})
    host, res = pair(**kw)
    assert "feet_in_pit" in res.weights and res.step_state.terrain.pit is not None
    for nh, nr in rollout_both(host, res, 25, scale=0.5):
        assert nr["depth"].shape == nh["depth"].shape
        assert_same_outputs(nh, nr)


def test_a_held_world_on_the_resident_step_as_on_the_host_step():
    """``HikingEnv.hold`` on the device-resident step: the held world ends no episode and never
    ticks (Warp still advances its simulation), and both paths' outputs stay the same."""
    host, res = pair(mode="student")
    th, tr = host.reset(), res.reset()
    host.hold([1]), res.hold([1])
    assert res.held.tolist() == host.held.tolist() == [False, True, False, False]
    assert res.step_state.held.device == res.step_state.tick.device and bool(res.step_state.held[1])
    g = torch.Generator().manual_seed(0)
    for _ in range(12):
        a = 2.0 * torch.randn(N, host.A, generator=g)
        out_h, th = host.step_and_maybe_reset(th.set("action", a))
        out_r, tr = res.step_and_maybe_reset(tr.set("action", a))
        nh, nr = out_h["next"], out_r["next"]
        assert_same_outputs(nh, nr)
        for out in (nh, nr):
            assert not out["done"][1].item() and not out["perception_tick"][1].item()
    res.reset()
    assert not res.held.any() and not bool(res.step_state.held.any())


def test_feed_forward_targets_of_the_resident_step_are_the_host_steps():
    """The gait clock's feed-forward PD targets, computed in float64 on both paths, reach the
    simulation as the same float32 values, bit for bit."""
    host, res = pair(mode="oracle", gait_period=0.8, gait_feedforward=0.5)
    steps = rollout_both(host, res, 12, scale=0.3)
    for _ in steps:
        ctrl_h = host.worlds.ctrl.astype(np.float32)
        ctrl_r = res.worlds.views["ctrl"].numpy()
        assert np.array_equal(ctrl_h, ctrl_r)
    phase = res.step_state.gait_phase()
    assert phase is not None and phase.dtype == torch.float64 and 0 < float(phase.max()) < 1


def test_resident_env_specs():
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=2, num_threads=1, physics="warp", resident=True))
    check_env_specs(env, seed=0)


def test_foot_scan_of_the_resident_step_equals_the_host_steps():
    """``foot_scan`` with ``foot_scan_far``: the feet's near and far scans, read on the device from
    Warp's body arrays and the device's height map, are the host's, on robots spawned among level-1
    gaps (their feet over the pits' walls); both envs pass torchrl's spec check. At a wall the terrain drops 1 m over one 0.1 m
    grid cell: the device's float32 sample points (float32 spacing ~2e-6 m at x ~ 20 m, a few of
    those after the rotation) then move a height by up to ~4e-5, so the scan is held to 1e-4
    there and to 1e-5 on 95% of its points (the flat ones)."""
    trails = trails_for(("gap",), 1, 3)
    trails.tile_start = trails.tile_waypoint.copy()  # spawn mid-trail, among the gaps
    kw = dict(mode="oracle", foot_scan=True, foot_scan_far=True, categories=("gap",), levels=(1,), variants=1)
    host = HikingEnv(HikingEnvConfig(**BASE, **kw), trails=trails)
    res = HikingEnv(HikingEnvConfig(**BASE, resident=True, **kw), trails=trails)
    assert host.observation_spec["scandots"].shape == res.observation_spec["scandots"].shape == (N, 132 + 90 + 70)
    for nh, nr in rollout_both(host, res, 6, scale=1.0):
        assert_same_outputs(nh.exclude("scandots"), nr.exclude("scandots"))
        feet_h, feet_r = nh["scandots"][:, 132:], nr["scandots"][:, 132:]
        assert torch.allclose(feet_h, feet_r, atol=1e-4, rtol=0.0)
        assert ((feet_h - feet_r).abs() < 1e-5).float().mean() > 0.95
    assert feet_h[:, :90].reshape(N, 2, 45).std(-1).max() > 0.3  # the scans see the gaps, not a flat floor
    assert feet_h[:, 90:].reshape(N, 2, 35).std(-1).max() > 0.3
    check_env_specs(res, seed=0)
    check_env_specs(host, seed=0)


def test_a_resident_step_copies_no_state_to_the_host(monkeypatch):
    env = HikingEnv(HikingEnvConfig(**BASE, mode="oracle", resident=True))
    td = env.reset()

    def refuse(*args, **kwargs):
        raise AssertionError("a resident step downloaded the simulation's outputs")

    monkeypatch.setattr(WarpWorlds, "_download", refuse)
    for _ in range(3):
        td = env.step(td.set("action", torch.zeros(N, env.A)))["next"]
    assert td["proprio"].device == env.device


def test_a_diverged_world_and_a_bad_action_on_the_resident_step():
    env = HikingEnv(HikingEnvConfig(**BASE, mode="oracle", resident=True))
    td = env.reset()
    home = env.worlds.home_qpos.copy()
    env.worlds.views["qvel"][2, 0] = float("nan")  # world 2 diverges in its next step
    action = torch.zeros(N, env.A)
    action[1, 3] = float("nan")  # world 1 sends a bad action
    out = env.step(td.set("action", action))["next"]
    assert out["info", "diverged"].flatten().tolist() == [False, False, True, False]
    assert out["truncated"].flatten().tolist() == [False, False, True, False]
    assert out["info", "bad_action"].flatten().tolist() == [False, True, False, False]
    assert env.diverged_total == 1 and env.bad_action_total == 1
    qpos = env.worlds.views["qpos"].double().numpy()
    assert np.allclose(qpos[2], home[2], atol=1e-6)  # back home
    assert torch.isfinite(out["proprio"]).all() and env.step_state.action[1].abs().max() == 0.0


def test_read_state_of_a_resident_env_is_the_host_readers():
    host, res = pair(mode="oracle")
    host.reset()
    res.reset()
    sh, sr = host.read_state([1, 3]), res.read_state([1, 3])
    assert set(sh) == set(sr)
    for key, value in sh.items():
        if value is None:
            assert sr[key] is None
        else:
            assert np.allclose(value, sr[key], atol=1e-5), key


def test_resident_settings_are_checked_and_resolved():
    with pytest.raises(ValueError, match="resident=True .* needs physics='warp', got physics='mujoco'"):
        HikingEnvConfig(resident=True)
    assert HikingEnvConfig(physics="warp", device="cuda").step_on_device
    assert HikingEnvConfig(physics="warp", device="cuda:1").step_on_device
    assert not HikingEnvConfig(physics="warp").step_on_device  # Warp's CPU device: the host step
    assert not HikingEnvConfig(physics="warp", device="cuda", resident=False).step_on_device
    assert not HikingEnvConfig(device="cuda").step_on_device
    cfg = env_config({"robot": "h1", "num_envs": 2, "physics": "warp", "resident": True}, mode="oracle")
    assert cfg.resident is True and cfg.step_on_device


def test_device_terrain_needs_the_grids_and_reads_them_as_the_host_does():
    class NoGrids:
        height_at_t = None

    with pytest.raises(ValueError, match=r"reads the terrain's grids .*NoGrids lacks \['height_at_t', 'edge_grid'\]"):
        DeviceTerrain(NoGrids(), "cpu")
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=1, num_threads=1, categories=("gap",), variants=1))
    terrain = DeviceTerrain(env.trails, "cpu", pits=True)
    rng = np.random.default_rng(0)
    x0, x1, y0, y1 = env.trails.grid.map.extent
    xy = np.stack([rng.uniform(x0 - 1, x1 + 1, 4000), rng.uniform(y0 - 1, y1 + 1, 4000)], axis=1)
    t = torch.as_tensor(xy, dtype=torch.float64)
    assert np.array_equal(terrain.edge(t).numpy(), env.trails.edge_at(xy))
    assert np.array_equal(terrain.pit(t).numpy(), env.trails.pit_at(xy))
    assert env.trails.pit_at(xy).any() and env.trails.edge_at(xy).any()
    assert np.allclose(terrain.heights(t).numpy(), env.trails.height_at(xy), atol=1e-4)
    # the nearest sample: half a cell either side of sample (1, 2) reads it
    mask = np.zeros((4, 5), dtype=bool)
    mask[1, 2] = True
    grid = MaskGrid(mask, (10.0, 20.0), 0.5, "cpu")
    pts = torch.tensor([[10.5, 21.0], [10.7, 21.2], [10.8, 21.0], [10.5, 21.3], [0.0, 0.0]])
    assert grid(pts).tolist() == [True, True, False, False, False]
