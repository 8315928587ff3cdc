"""HikingEnv behaviour (issue 4): specs, terminations, resets, determinism, sensors, metrics.

Why one file of ~550 lines: every test builds the same small env (``BoxScene`` and a tiny trail
grid) and checks one behaviour of its step; the env's parts have their own files."""

import math

import numpy as np
import pytest
import torch
from scenes import BoxScene
from tensordict import TensorDict
from torchrl.envs import check_env_specs

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.randomization import DomainRandConfig


def make(robot="h1", n=3, mode="oracle", scene=None, **kw):
    kw.setdefault("num_threads", 1)
    cfg = HikingEnvConfig(robot=robot, num_envs=n, mode=mode, **kw)
    return HikingEnv(cfg, trails=scene or BoxScene())


def act(env, a=None):
    a = torch.zeros(env.batch_size[0], env.A) if a is None else a
    return env.step(TensorDict({"action": a}, batch_size=env.batch_size))["next"]


def quiet(**kw):
    """Deterministic spawn, no randomisation: for scripted checks."""
    return dict(spawn_jitter_xy=0.0, spawn_jitter_yaw=0.0, domain_rand=DomainRandConfig.off(), **kw)


@pytest.mark.parametrize("robot", ["h1", "g1"])
@pytest.mark.parametrize("mode", ["oracle", "student", "eval"])
def test_check_env_specs(robot, mode):
    env = make(robot, n=2, mode=mode)
    check_env_specs(env, seed=0)
    A = 10 if robot == "h1" else 12
    assert env.action_spec.shape == (2, A)
    assert env.observation_spec["proprio"].shape == (2, 3 + 2 + 3 * A + 2)
    assert ("depth" in env.observation_spec.keys()) == (mode != "oracle")


def test_reward_terms_are_reward_entries_in_next_only():
    """The weighted terms are reward-spec entries: in "next" beside the reward they sum to, not
    carried into the next root by step_mdp, not produced by a reset."""
    env = make(n=3, only_positive_rewards=False)  # the reward is then the plain sum of its terms
    assert env.reward_key == "reward"
    assert set(env.reward_keys) == {"reward", *(("reward_terms", k) for k in env.weights)}
    assert "reward_terms" not in env.observation_spec.keys()
    td = env.reset()
    assert "reward_terms" not in td.keys()
    td["action"] = torch.zeros(3, env.A)
    stepped, root = env.step_and_maybe_reset(td)
    terms = stepped["next", "reward_terms"]
    assert set(terms.keys()) == set(env.weights)
    torch.testing.assert_close(sum(terms.values()), stepped["next", "reward"])
    assert "reward_terms" not in root.keys() and "reward" not in root.keys()
    assert "episode" in root.keys()  # observation entries are carried


def test_step_processing_equals_torchrl_full_processing():
    """The env's lighter post-step processing gives what torchrl's gives (its reward reshaping is
    a no-op here), and torchrl's type checks pass on the step's output."""
    from torchrl.envs import EnvBase

    env = make(n=2, mode="student")
    td = env.reset()
    td["action"] = 0.3 * torch.ones(2, env.A)
    out = env._step(td)
    fast, full = env._step_proc_data(out.clone()), EnvBase._step_proc_data(env, out.clone())
    assert set(fast.keys(True, True)) == set(full.keys(True, True))
    for key in full.keys(True, True):  # time_to_reach is NaN where no episode ended
        torch.testing.assert_close(fast[key], full[key], rtol=0, atol=0, equal_nan=True)
    env.run_type_checks = True
    assert env.step(td)["next", "reward"].shape == (2, 1)


def test_reset_cells_iterate_like_a_world_by_world_set():
    """The reset draws one tile batch per (level, category) cell; the cells come from arrays, in
    the iteration order of a set built world by world (the random stream of recorded runs)."""
    from legoh_rl.envs.hiking import _cells

    rng = np.random.default_rng(0)
    for _ in range(500):
        n = int(rng.integers(1, 300))
        levels, cats = rng.integers(0, int(rng.integers(1, 12)), n), rng.integers(0, int(rng.integers(1, 8)), n)
        by_world = {(int(lv), int(c)) for lv, c in zip(levels, cats, strict=True)}
        assert list(_cells(levels, cats)) == list(by_world)
    assert _cells(np.array([2, 0, 2]), np.array([1, 3, 1])) == {(2, 1), (0, 3)}


def test_partial_reset_isolates_worlds():
    env = make(n=3)
    env.reset()
    for _ in range(5):
        act(env, 0.5 * torch.randn(3, env.A))
    before = env.worlds.qpos.copy()
    td = env.reset(TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, batch_size=[3]))
    assert np.array_equal(env.worlds.qpos[[0, 2]], before[[0, 2]])
    assert not np.array_equal(env.worlds.qpos[1], before[1])
    assert env.episode_step.tolist() == [5, 0, 5]
    assert not td["done"].any()


def test_partial_reset_refreshes_only_the_reset_rows_and_they_match_a_full_recompute():
    """A partial reset recomputes the observations of the reset worlds only; every row of its
    output equals what a full recompute from the current state gives, and the reset worlds read
    a fresh depth frame (perception tick True)."""
    env = make(n=4, mode="student")
    env.reset()
    for _ in range(3):
        act(env, 0.5 * torch.randn(4, env.A))
    stepped = act(env, 0.5 * torch.randn(4, env.A))
    mask = torch.tensor([[False], [True], [False], [True]])
    td = env._reset(TensorDict({"_reset": mask}, batch_size=[4]))
    full = env.step_state._refresh_observations(np.arange(env.cfg.num_envs))
    for key, value in full.items():
        assert np.allclose(td[key].numpy(), np.asarray(value, dtype=np.float32)), key
    assert td["perception_tick"].reshape(-1).tolist() == [False, True, False, True]
    keep = [0, 2]  # untouched worlds: the same observation as after the step
    for key in ("proprio", "scandots", "goal_gps", "privileged", "depth"):
        assert torch.equal(td[key][keep], stepped[key][keep]), key
    assert not torch.equal(td["proprio"][[1, 3]], stepped["proprio"][[1, 3]])


def test_same_seed_same_rollout():
    outs = []
    for _ in range(2):
        env = make(n=2, mode="student")
        env.set_seed(3)
        torch.manual_seed(0)
        outs.append(env.rollout(15))
    for key in ("proprio", "depth", "scandots", "privileged", "reward"):
        assert torch.equal(outs[0]["next", key], outs[1]["next", key])


def test_fall_terminates_with_time_to_fall():
    env = make(n=2, **quiet())
    env.reset()
    for _ in range(3):
        act(env)
    roll = 1.3  # past the 1.0 rad threshold
    env.worlds.qpos[1, 3:7] = [math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0]
    env.worlds.batch.forward()
    nxt = act(env)
    assert nxt["terminated"].squeeze(-1).tolist() == [False, True]
    assert not nxt["truncated"].any()
    assert nxt["episode", "ttf"][1].item() == pytest.approx(4 * env.dt)
    assert nxt["episode", "success"][1].item() == 0.0


def test_timeout_truncates():
    env = make(n=1, **quiet(episode_length_s=0.1))
    env.reset()
    flags = [act(env) for _ in range(5)]
    assert [bool(f["truncated"]) for f in flags] == [False, False, False, False, True]
    assert not any(bool(f["terminated"]) for f in flags)


def teleport_along(env, xs, fall_at=None):
    """Walk world 0 along y=0 by setting its base each step; return the step outputs."""
    outs = []
    for k, x in enumerate(xs):
        q = env.worlds.qpos
        q[0, 0], q[0, 1] = x, 0.0
        q[0, 3:7] = [1.0, 0.0, 0.0, 0.0]
        env.worlds.qvel[0] = 0.0
        if fall_at is not None and k == fall_at:
            q[0, 2] = 0.3  # base far below its target height: a fall
        env.worlds.batch.forward()
        outs.append(act(env))
        if outs[-1]["done"].any():
            break
    return outs


def test_scripted_success_metrics():
    """Teleported along the route to P_B (6 m, goals every 1.5 m) at 0.1 m per step."""
    env = make(n=1, mode="eval", scene=BoxScene(trail_length=6.0, goal_spacing=1.5), **quiet())
    env.reset()
    outs = teleport_along(env, np.arange(1, 80) * 0.1)
    last = outs[-1]
    assert bool(last["terminated"]) and not bool(last["truncated"])
    # eval radius 0.89 m: first x with 6 - x < 0.89 is 5.2 (step 52)
    assert len(outs) == 52
    ep = last["episode"]
    assert ep["success"].item() == 100.0
    assert ep["trail_completion"].item() == pytest.approx(100.0)  # goals at 1.5, 3.0, 4.5 m
    assert ep["traverse_rate"].item() == 100.0
    assert ep["time_to_reach"].item() == pytest.approx(52 * env.dt)
    assert ep["ttf"].item() == pytest.approx(52 * env.dt)


def test_scripted_fall_metrics():
    env = make(n=1, mode="eval", scene=BoxScene(trail_length=6.0, goal_spacing=1.5), **quiet())
    env.reset()
    outs = teleport_along(env, np.arange(1, 80) * 0.1, fall_at=19)  # at x = 2.0 m
    ep = outs[-1]["episode"]
    assert len(outs) == 20 and bool(outs[-1]["terminated"])
    assert ep["success"].item() == 0.0
    assert math.isnan(ep["time_to_reach"].item())
    assert ep["ttf"].item() == pytest.approx(20 * env.dt)
    assert ep["trail_completion"].item() == pytest.approx(100.0 / 3)  # passed the goal at 1.5 m
    assert ep["traverse_rate"].item() == pytest.approx(100.0 * 2.0 / 6.0, abs=1.0)


def test_depth_reads_wall_distance():
    """H1 facing a tall wall 1.2 m ahead: the optical axis meets it at z-depth (1.2 - x_cam)/cos 45."""
    wall = ([1.2 + 0.1, 0.0, 1.5], [0.1, 2.0, 1.5])
    env = make(n=1, mode="student", scene=BoxScene(boxes=[wall]), **quiet())
    td = env.reset()
    cam = env.worlds.cam_xpos[0, env.built.camera_id]
    expect = (1.2 - cam[0]) / math.cos(math.radians(45.0))
    c = env.cfg.depth_camera
    centre = td["depth"][0, 0, 31:33, 31:33].mean().item() * (c.far - c.near) + c.near
    assert centre == pytest.approx(expect, abs=0.03)
    # the exact reference renderer (MuJoCo rays) reads the same distance
    ids = np.arange(1)
    exact = env.camera.render_exact(env.worlds.batch, env.worlds.cam_xpos[ids, env.built.camera_id],
                                    env.worlds.cam_xmat[ids, env.built.camera_id].reshape(-1, 3, 3), ids)
    assert exact.shape == (1, 1, 64, 64)
    assert exact[0, 0, 31:33, 31:33].mean() * (c.far - c.near) + c.near == pytest.approx(expect, abs=0.01)
    # without the wall the same rays reach the ground at z-depth h / sin 45 (robot body not seen)
    env2 = make(n=1, mode="student", **quiet())
    td2 = env2.reset()
    ground = td2["depth"][0, 0, 31:33, 31:33].mean().item() * (c.far - c.near) + c.near
    assert ground == pytest.approx(cam[2] / math.sin(math.radians(45.0)), abs=0.03)


def test_depth_refreshes_every_fifth_step():
    env = make(n=2, mode="student")
    env.reset()
    ticks = [bool(act(env, 0.3 * torch.randn(2, env.A))["perception_tick"][0]) for _ in range(10)]
    assert ticks == [False, False, False, False, True] * 2


def test_the_global_perception_clock_ticks_every_world_together_after_a_partial_reset():
    """perception_clock="global": the 5 steps are counted on the env's step count, so a world reset
    mid-way ticks at its reset and then with the others, where the episode clock keeps its own phase;
    the depth frame changes exactly on the ticks."""
    ticks = {}
    for clock in ("episode", "global"):
        env = make(n=3, mode="student", perception_clock=clock)
        env.reset()
        for _ in range(2):
            before = act(env, 0.3 * torch.randn(3, env.A))
        td = env._reset(TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, batch_size=[3]))
        assert td["perception_tick"].reshape(-1).tolist() == [False, True, False]
        assert torch.equal(td["depth"][[0, 2]], before["depth"][[0, 2]])  # the others hold their frame
        rows, depth = [], td["depth"].clone()
        for _ in range(8):  # env steps 3 .. 10
            out = act(env, 0.3 * torch.randn(3, env.A))
            tick = out["perception_tick"].reshape(-1)
            changed = (out["depth"] != depth).flatten(1).any(1)
            assert torch.equal(changed, tick), clock  # a new frame exactly where a tick is
            depth = out["depth"].clone()
            rows.append(tick.tolist())
        ticks[clock] = rows
    # episode clock: worlds 0 and 2 tick at their episode steps 5 and 10 (env steps 5, 10), world 1
    # at its episode step 5 (env step 7); global: all three at env steps 5 and 10
    assert [i + 3 for i, r in enumerate(ticks["episode"]) if r[0]] == [5, 10]
    assert [i + 3 for i, r in enumerate(ticks["episode"]) if r[1]] == [7]
    assert [i + 3 for i, r in enumerate(ticks["global"]) if any(r)] == [5, 10]
    assert all(all(r) or not any(r) for r in ticks["global"])
    with pytest.raises(ValueError, match="perception_clock"):
        HikingEnvConfig(perception_clock="camera")


def test_scandots_read_a_step():
    step = ([1.25, 0.0, 0.05], [0.75, 2.0, 0.05])  # 10 cm step covering x in [0.5, 2.0]
    env = make(n=1, scene=BoxScene(boxes=[step]), **quiet())
    td = env.reset()
    dots = td["scandots"][0].reshape(12, 11)
    xs = np.linspace(-0.45, 1.2, 12) + env.worlds.qpos[0, 0]
    on_step = xs > 0.5 + 1e-6
    diff = dots[on_step].mean() - dots[~on_step].mean()
    assert diff.item() == pytest.approx(0.1, abs=1e-5)
    assert dots[~on_step].std().item() < 1e-6


def test_foot_scan_extends_scandots_and_reads_a_step_ahead_of_the_feet():
    """``foot_scan``: 90 columns after the 132 scandots; at the spawn (yaw 0, no jitter) the H1
    ankles stand at x = 0, so a 5 cm step from x = 0.175 lies under grid rows 6-8 (0.2-0.3 m
    ahead) of both feet and not under rows 0-5 (up to 0.15 m ahead). Off the step each point
    reads the floor below the sole, -(z_ankle - 0.065); on it 5 cm more."""
    step = ([1.175, 0.0, 0.025], [1.0, 2.0, 0.025])
    env = make(n=1, scene=BoxScene(boxes=[step]), foot_scan=True, **quiet())
    assert env.observation_spec["scandots"].shape == (1, 132 + 90)
    check_env_specs(env, seed=0)
    td = env.reset()
    scan = td["scandots"][0, 132:].reshape(2, 9, 5).double().numpy()  # (left, right), forward, left
    feet = env.worlds.xpos[0, env.built.foot_body_ids]
    np.testing.assert_allclose(feet[:, 0], 0.0, atol=1e-3)
    floor = -(feet[:, 2] - env.robot.foot_rest_height)
    np.testing.assert_allclose(scan[:, :6], np.broadcast_to(floor[:, None, None], (2, 6, 5)), atol=1e-6)
    np.testing.assert_allclose(scan[:, 6:], np.broadcast_to(floor[:, None, None] + 0.05, (2, 3, 5)), atol=1e-6)
    assert torch.equal(td["scandots"][:, :132], make(n=1, scene=BoxScene(boxes=[step]), **quiet()).reset()["scandots"])


def test_the_far_foot_scan_follows_the_near_one_and_reads_a_step_beyond_its_reach():
    """``foot_scan_far``: 70 columns after the near scan's 90 (both feet's 35, left first); the
    near columns are those of a ``foot_scan`` env alone. A 5 cm step from x = 0.475, past the near
    grid's 0.3 m, lies under far rows 3-6 (0.5-0.65 m ahead of the ankles at x = 0) and not under
    rows 0-2 (0.35-0.45 m) nor any near row. ``foot_scan_far`` alone is refused."""
    step = ([1.2375, 0.0, 0.025], [0.7625, 2.0, 0.025])
    env = make(n=1, scene=BoxScene(boxes=[step]), foot_scan=True, foot_scan_far=True, **quiet())
    assert env.observation_spec["scandots"].shape == (1, 132 + 90 + 70)
    check_env_specs(env, seed=0)
    td = env.reset()
    feet = env.worlds.xpos[0, env.built.foot_body_ids]
    np.testing.assert_allclose(feet[:, 0], 0.0, atol=1e-3)
    floor = -(feet[:, 2] - env.robot.foot_rest_height)[:, None, None]
    far = td["scandots"][0, 222:].reshape(2, 7, 5).double().numpy()
    np.testing.assert_allclose(far[:, :3], np.broadcast_to(floor, (2, 3, 5)), atol=1e-6)
    np.testing.assert_allclose(far[:, 3:], np.broadcast_to(floor + 0.05, (2, 4, 5)), atol=1e-6)
    near = make(n=1, scene=BoxScene(boxes=[step]), foot_scan=True, **quiet()).reset()["scandots"]
    assert near.shape == (1, 222) and torch.equal(td["scandots"][:, :222], near)
    np.testing.assert_allclose(near[0, 132:].reshape(2, 45).double().numpy(),
                               np.broadcast_to(floor[:, :, 0], (2, 45)), atol=1e-6)
    with pytest.raises(ValueError, match=r"foot_scan_far=True .* needs foot_scan=True"):
        make(n=1, foot_scan_far=True, **quiet())


def test_bad_actions():
    env = make(n=2)
    env.reset()
    with pytest.raises(ValueError, match=r"action must have shape \(2, 10\).*got \(2, 12\)"):
        act(env, torch.zeros(2, 12))
    a = torch.zeros(2, env.A)
    a[1, 3] = float("nan")
    nxt = act(env, a)
    assert nxt["info", "bad_action"].squeeze(-1).tolist() == [False, True]
    assert env.bad_action_total == 1
    assert torch.isfinite(nxt["proprio"]).all()


def test_time_spent_counts_steps_their_physics_and_resets():
    env = make()
    assert env.time_spent == {"step": 0.0, "physics": 0.0, "reset": 0.0}
    td = env.reset()
    after_reset = dict(env.time_spent)
    assert after_reset["reset"] > 0 and after_reset["step"] == after_reset["physics"] == 0
    env.rand_step(td)
    assert 0 < env.time_spent["physics"] < env.time_spent["step"]
    assert env.time_spent["reset"] == after_reset["reset"]  # a step without done worlds resets nothing


def test_diverged_world_resets_alone_and_is_reported():
    env = make(n=3)
    env.reset()
    act(env)
    env.worlds.qvel[2] = np.nan
    nxt = act(env)
    assert nxt["info", "diverged"].squeeze(-1).tolist() == [False, False, True]
    assert nxt["truncated"].squeeze(-1).tolist() == [False, False, True]
    assert env.diverged_total == 1
    assert torch.isfinite(nxt["proprio"]).all()


def test_bad_config_values():
    with pytest.raises(ValueError, match="unknown mode 'train'"):
        HikingEnvConfig(mode="train")
    with pytest.raises(ValueError, match="num_envs must be a positive integer, got 0"):
        HikingEnvConfig(num_envs=0)
    with pytest.raises(ValueError, match=r"levels must be a non-empty list of integers in \[0, 4\], got \(7,\): 7 is not"):
        make(levels=(7,))


def test_gymnasium_check_env():
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    import legoh_rl.envs  # noqa: F401  (registers the ids)

    env = gymnasium.make("LegoH/Hike-H1-v0", trails=BoxScene(), num_threads=1)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs["proprio"].shape == (37,) and obs["proprio"].dtype == np.float32


def test_domain_randomisation_per_world_in_paper_ranges():
    env = make(n=4, scene=BoxScene())
    td = env.reset()
    dr, w, b = env.randomizer, env.worlds, env.built
    assert ((dr.friction >= 0.6) & (dr.friction <= 2.0)).all() and np.unique(dr.friction).size == 4
    assert ((dr.mass_offset >= 0) & (dr.mass_offset <= 3)).all()
    assert (np.abs(dr.com_offset) <= 0.2).all()
    assert ((dr.motor_strength >= 0.8) & (dr.motor_strength <= 1.2)).all()
    mass = w.batch.expanded("body_mass")[:, b.base_body_id]
    np.testing.assert_allclose(mass, w.nominal("body_mass")[b.base_body_id] + dr.mass_offset)
    kp = w.batch.expanded("actuator_gainprm")[:, b.actuator_ids, 0]
    np.testing.assert_allclose(kp, np.array(env.robot.kp) * dr.motor_strength)
    geom = b.robot_geom_ids[w.model.geom_contype[b.robot_geom_ids] != 0][0]
    np.testing.assert_allclose(w.batch.expanded("geom_friction")[:, geom, 0], dr.friction)
    priv = td["privileged"].numpy()
    np.testing.assert_allclose(priv[:, 3], dr.friction, rtol=1e-6)
    np.testing.assert_allclose(priv[:, 8:], dr.motor_strength, rtol=1e-6)
    # same seed, same draws
    env2 = make(n=4, scene=BoxScene())
    env2.reset()
    np.testing.assert_array_equal(env2.randomizer.friction, dr.friction)


def test_eval_mode_runs_the_nominal_robot_unless_eval_domain_rand():
    nominal = make(n=4, mode="eval", scene=BoxScene())
    nominal.reset()
    dr = nominal.randomizer
    assert np.all(dr.friction == dr.nominal_friction) and not dr.mass_offset.any() and not dr.com_offset.any()
    assert np.all(dr.motor_strength == 1.0) and dr.delay_steps(0) == 0 and not dr.cfg.push
    rand = make(n=4, mode="eval", scene=BoxScene(), eval_domain_rand=True)
    rand.reset()
    dr = rand.randomizer
    assert ((dr.friction >= 0.6) & (dr.friction <= 2.0)).all() and np.unique(dr.friction).size == 4
    assert ((dr.motor_strength >= 0.8) & (dr.motor_strength <= 1.2)).all() and dr.mass_offset.any()
    assert dr.cfg.push and dr.delay_steps(0) == 1  # the training's late action delay from the first step
    # the delay acts: a step's action reaches the PD targets one step later
    a = torch.zeros(4, rand.A)
    a[:, 0] = 0.4
    act(rand, a)
    targets = lambda: rand.worlds.ctrl[:, rand.built.actuator_ids[0]]  # noqa: E731
    np.testing.assert_allclose(targets(), rand.q_default[0])
    act(rand, torch.zeros(4, rand.A))
    np.testing.assert_allclose(targets(), rand.q_default[0] + rand.robot.action_scale * 0.4)
    with pytest.raises(ValueError, match="eval_domain_rand .* needs mode='eval', got mode='oracle'"):
        make(eval_domain_rand=True)


def test_eval_domain_rand_can_draw_named_terms_alone():
    """A tuple of terms: those drawn, the others nominal (pushes alone: no friction, mass, motor
    or delay draws; friction and delay alone: no pushes or mass)."""
    pushes = make(n=4, mode="eval", scene=BoxScene(), eval_domain_rand=("push",))
    pushes.reset()
    dr = pushes.randomizer
    assert dr.cfg.push and np.all(dr.friction == dr.nominal_friction) and not dr.mass_offset.any()
    assert np.all(dr.motor_strength == 1.0) and dr.delay_steps(0) == 0
    both = make(n=4, mode="eval", scene=BoxScene(), eval_domain_rand=["friction", "action_delay"])
    both.reset()
    dr = both.randomizer
    assert both.cfg.eval_domain_rand == ("friction", "action_delay")
    assert np.unique(dr.friction).size == 4 and dr.delay_steps(0) == 1  # delay from the first step
    assert not dr.cfg.push and not dr.mass_offset.any() and not dr.com_offset.any() and np.all(dr.motor_strength == 1.0)
    assert HikingEnvConfig(mode="eval", eval_domain_rand="push").active_domain_rand == \
        HikingEnvConfig(mode="eval", eval_domain_rand=("push",)).active_domain_rand
    with pytest.raises(ValueError, match=r"eval_domain_rand: unknown domain randomisation term 'wind'; valid: \['friction'"):
        HikingEnvConfig(mode="eval", eval_domain_rand=("push", "wind"))
    with pytest.raises(ValueError, match=r"eval_domain_rand must be true, false or a non-empty list of terms .*, got \(\)"):
        HikingEnvConfig(mode="eval", eval_domain_rand=())


def test_curriculum_moves_levels_by_progress():
    from legoh_rl.envs.curriculum import Curriculum, CurriculumConfig

    c = Curriculum(CurriculumConfig(), num_levels=5, levels=np.array([0, 2, 2, 4, 4]))
    rng = np.random.default_rng(0)
    ids = np.arange(5)
    progress = np.array([9.0, 1.0, 5.0, 9.0, 0.0])
    new = c.update(ids, progress, np.full(5, 10.0), np.array([False, False, False, False, False]), rng)
    # 90% -> up; 10% -> down; 50% -> stays; top level + up -> random level; 0% at level 4 -> 3
    assert new[0] == 1 and new[1] == 1 and new[2] == 2 and 0 <= new[3] < 5 and new[4] == 3
    assert c.update(np.array([1]), np.array([0.0]), np.array([10.0]), np.array([True]), rng)[0] == 2  # reached


def test_world_categories_round_robin_or_weighted():
    from legoh_rl.envs.curriculum import world_categories

    np.testing.assert_array_equal(world_categories(5, np.array([0, 1, 2])), [0, 1, 2, 0, 1])
    # quotas 2 / 4 / 4: exact
    np.testing.assert_array_equal(np.bincount(world_categories(10, np.array([0, 1, 2]), [1, 2, 2])), [2, 4, 4])
    # quotas 10 * (0.25, 0.375, 0.375) = 2.5 / 3.75 / 3.75: floors 2 / 3 / 3, the two largest remainders get one more
    np.testing.assert_array_equal(np.bincount(world_categories(10, np.array([0, 1, 2]), [2, 3, 3])), [2, 4, 4])
    # 256 worlds over five categories weighted 1 / 1.5 / 1 / 1.5 / 0.6
    counts = np.bincount(world_categories(256, np.arange(5), [1, 1.5, 1, 1.5, 0.6]))
    assert counts.sum() == 256 and counts.tolist() == [46, 69, 46, 68, 27]
    with pytest.raises(ValueError, match="one positive weight per category"):
        world_categories(4, np.array([0, 1]), [1.0])
    with pytest.raises(ValueError, match="category_weights"):
        HikingEnvConfig(categories=("gap", "ditch"), category_weights=(1.0, 0.0))
    with pytest.raises(ValueError, match="feet_edge_from_level"):
        HikingEnvConfig(feet_edge_from_level=-1)


def test_feet_in_pit_counts_feet_standing_over_pit_samples():
    # robots spawn at x = 0 and stand with both feet down: both over the pit band, or neither
    for band, expect in (((-0.5, 0.5), 2.0), ((2.0, 3.0), 0.0)):
        env = make(n=2, scene=BoxScene(pit_x=band), reward_overrides={"feet_in_pit": -3.0},
                   spawn_jitter_xy=0.0, spawn_jitter_yaw=0.0)
        env.reset()
        for _ in range(10):
            nxt = act(env)
        contact = env.read_state()["contact"]
        assert contact.all()
        np.testing.assert_allclose(nxt["reward_terms", "feet_in_pit"].numpy().ravel(), [-3.0 * env.dt * expect] * 2,
                                   rtol=1e-5)

    class NoPits(BoxScene):
        pit_at = None

    with pytest.raises(ValueError, match="feet_in_pit needs trails with pit_at"):
        make(n=1, scene=NoPits(), reward_overrides={"feet_in_pit": -1.0})


def test_base_height_error_cap_reaches_the_base_height_term():
    """env.base_height_error_cap: the term counts min(h - h_target, cap)^2 of the pelvis height the
    env reads (cap 0: nothing of a pelvis above its target, all of one below it)."""
    for cap in (None, 0.0):
        env = make(n=2, **quiet(base_height_error_cap=cap))
        env.reset()
        env.worlds.qpos[0, 2] += 0.3  # world 0 lifted 0.3 m: its pelvis well above its target
        nxt = act(env)
        err = env.read_state()["base_height"] - env.robot.base_height_target
        assert err[0] > 0.1 and err[1] < 0.1
        counted = err if cap is None else np.minimum(err, cap)
        np.testing.assert_allclose(nxt["reward_terms", "base_height"].numpy().ravel(),
                                   -100.0 * env.dt * counted ** 2, rtol=1e-4, atol=1e-7)


def test_only_positive_rewards_clips_the_total_not_the_terms():
    for clip in (True, False):
        env = make(n=2, only_positive_rewards=clip)
        env.reset()
        nxt = act(env, 2.0 * torch.ones(2, env.A))  # a violent step: penalties dominate
        terms = sum(v for v in nxt["reward_terms"].values())
        expect = terms.clamp_min(0.0) if clip else terms  # no termination term by default
        torch.testing.assert_close(nxt["reward"], expect, rtol=1e-5, atol=1e-6)
        assert (terms < 0).any()


@pytest.mark.parametrize("robot", ["h1", "g1"])
def test_gait_terms_read_foot_lift_and_slip(robot):
    env = make(robot=robot, n=2, **quiet(reward_overrides={"feet_slip": -1.0, "feet_clearance": -1.0}))
    env.reset()
    for _ in range(15):  # settle onto the flat ground
        nxt = act(env)
    s = env.read_state()
    assert s["contact"].all()
    np.testing.assert_allclose(s["foot_lift"], 0.0, atol=0.01)  # foot_rest_height is the standing height
    assert np.abs(nxt["reward_terms", "feet_slip"].numpy()).max() < 0.05 * env.dt
    # slide world 0 by 5 cm between two control steps: its feet move ~0.05 / dt while in contact
    env.worlds.qpos[0, 0] += 0.05
    env.worlds.batch.forward(np.array([0]))
    nxt = act(env)
    slip = -nxt["reward_terms", "feet_slip"].numpy() / env.dt
    assert slip[0] == pytest.approx(2 * 0.05 / env.dt, rel=0.1)
    assert slip[1] < 0.05


def test_gait_clock_in_proprio_and_contact_reward():
    base = make(n=2, **quiet())
    env = make(n=2, **quiet(gait_period=0.8, reward_overrides={"gait_contact": 1.0}))
    check_env_specs(env)
    assert env.observation_spec["proprio"].shape[-1] == base.observation_spec["proprio"].shape[-1] + 2
    env.reset()
    for _ in range(15):
        nxt = act(env)
    phase = 15 * env.dt / 0.8  # 0.375 of a period after 15 control steps
    np.testing.assert_allclose(nxt["proprio"][:, -2:].numpy(),
                               np.tile([math.sin(2 * math.pi * phase), math.cos(2 * math.pi * phase)], (2, 1)), atol=1e-6)
    # both feet on the ground at phase 0.375: the left leg is in stance, the right in swing -> 1 of 2
    assert env.read_state()["contact"].all()
    np.testing.assert_allclose(nxt["reward_terms", "gait_contact"].numpy(), 1.0 * env.dt, rtol=1e-6)
    # a reset world's clock starts again at phase 0; the other world's runs on
    td = env.reset(TensorDict({"_reset": torch.tensor([[True], [False]])}, batch_size=[2]))
    np.testing.assert_allclose(td["proprio"][0, -2:].numpy(), [0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(env.gait_phase(), [0.0, phase])
    # no term reads the swing reference here, so the reward state carries none
    state = env.read_state()
    state["goal_dirs_w"] = env.step_state._goal_dirs(state["pos"])
    assert env.step_state._reward_state(state).gait_ref_q is None


def test_gait_options_refused_when_bad():
    with pytest.raises(ValueError, match="gait_period must be a number >= 0, got -1"):
        HikingEnvConfig(gait_period=-1.0)
    with pytest.raises(ValueError, match=r"gait_stance must be a number in \(0, 1\), got 1.0"):
        HikingEnvConfig(gait_stance=1.0)
    with pytest.raises(ValueError, match="gait_contact needs a gait clock.*gait_period=0.0"):
        HikingEnvConfig(reward_overrides={"gait_contact": 1.0})
    with pytest.raises(ValueError, match="gait_joint_ref needs a gait clock"):
        HikingEnvConfig(reward_overrides={"gait_joint_ref": 1.0})
    with pytest.raises(ValueError, match="gait_amplitude must be a number >= 0, got -0.1"):
        HikingEnvConfig(gait_amplitude=-0.1)
    with pytest.raises(ValueError, match="gait_feedforward must be a number >= 0, got -1.0"):
        HikingEnvConfig(gait_period=0.8, gait_feedforward=-1.0)
    with pytest.raises(ValueError, match="gait_feedforward=1.0 needs a gait clock.*gait_period=0.0"):
        HikingEnvConfig(gait_feedforward=1.0)


def test_gait_joint_ref_reads_the_clocks_reference():
    env = make(n=2, **quiet(gait_period=0.8, gait_amplitude=0.2, reward_overrides={"gait_joint_ref": 1.0}))
    env.reset()
    for _ in range(10):  # phase 0.25: the right leg's reference is folded by 0.2 / 0.4 / 0.2
        nxt = act(env)
    ref = env.gait_reference()
    np.testing.assert_allclose(ref - env.q_default, np.tile([0, 0, 0, 0, 0, 0, 0, -0.2, 0.4, -0.2], (2, 1)), atol=1e-9)
    d = np.linalg.norm(env.read_state()["q"] - ref, axis=1)
    expected = (np.exp(-2 * d) - 0.2 * np.minimum(d, 0.5)) * env.dt
    np.testing.assert_allclose(nxt["reward_terms", "gait_joint_ref"].numpy()[:, 0], expected, rtol=1e-5)


def test_gait_feedforward_adds_the_clocks_swing_to_the_pd_targets():
    env = make(n=2, **quiet(gait_period=0.8, gait_amplitude=0.2, gait_feedforward=0.5))
    plain = make(n=2, **quiet(gait_period=0.8, gait_amplitude=0.2))
    targets = lambda e: e.worlds.ctrl[:, e.worlds.built.actuator_ids].copy()  # noqa: E731
    for e in (env, plain):
        e.reset()
        for _ in range(10):  # the policy observes phase 0.25 before the 11th action
            act(e)
    nxt = act(env, torch.full((2, env.A), 0.4))
    act(plain, torch.full((2, env.A), 0.4))
    scale = env.robot.action_scale
    # at phase 0.25 the right leg's reference is folded by 0.2 / 0.4 / 0.2; half of it is fed forward
    swing = 0.5 * np.array([0, 0, 0, 0, 0, 0, 0, -0.2, 0.4, -0.2])
    np.testing.assert_allclose(targets(env), np.tile(env.q_default + scale * 0.4 + swing, (2, 1)), atol=1e-6)
    np.testing.assert_allclose(targets(plain), np.tile(plain.q_default + scale * 0.4, (2, 1)), atol=1e-6)
    # the swinging (right) knee bends further than the stance knee once the targets act
    for _ in range(4):
        nxt = act(env)
    q = env.read_state()["q"]
    assert (q[:, 8] - q[:, 3] > 0.05).all(), q[:, [3, 8]]
    assert nxt["proprio"].shape[-1] == plain.observation_spec["proprio"].shape[-1]


def test_set_gait_feedforward_changes_the_pd_targets_from_the_next_step():
    """Zero actions: the targets are the default pose plus gain x the clock's swing offsets."""
    env = make(n=2, gait_period=0.8, gait_feedforward=1.0, **quiet())
    env.reset()
    act_ids = env.worlds.built.actuator_ids
    for _ in range(10):  # into the clock's swing (phase 0.25 at step 10 of 0.02 s)
        act(env)
    offsets = env.gait_reference() - env.q_default
    assert np.abs(offsets).max() > 0.1
    env.set_gait_feedforward(0.25)
    phase_offsets = env.gait_reference() - env.q_default
    act(env)
    np.testing.assert_allclose(env.worlds.ctrl[:, act_ids], env.q_default + 0.25 * phase_offsets)
    env.set_gait_feedforward(0.0)
    act(env)
    np.testing.assert_allclose(env.worlds.ctrl[:, act_ids], np.broadcast_to(env.q_default, (2, env.A)))
    with pytest.raises(ValueError, match=r"gait_feedforward must be a number >= 0, got -1.0"):
        env.set_gait_feedforward(-1.0)
    no_clock = make(n=1)
    with pytest.raises(ValueError, match=r"gait_feedforward=0.5 needs a gait clock"):
        no_clock.set_gait_feedforward(0.5)


def test_pit_depths_reach_the_training_terrain_and_not_the_benchmark():
    depths = (0.1, 0.3, 0.6, 1.0, 1.0)
    env = HikingEnv(HikingEnvConfig(num_envs=2, categories=("gap",), variants=1, num_threads=1, pit_depths=depths))
    assert env.trails.grid.config.pit_depths == depths
    env.close()
    with pytest.raises(ValueError, match=r"pit_depths=\[0.1, 0.3, 0.6, 1.0, 1.0\] is a training setting"):
        HikingEnvConfig(mode="eval", pit_depths=depths)


def test_category_reward_scales_weight_a_term_by_each_worlds_trail_category():
    """env.category_reward_scales: the same step of the same worlds, with and without scales; the
    scaled term is the unscaled one times its world's category's scale (Gap 0, Hurdle 0.5), every
    other term and the unnamed categories unchanged; a scaled term without a weight is refused."""
    base = dict(categories=["hurdle", "gap"], levels=[0], variants=1, gait_period=0.8,
                reward_overrides={"gait_contact": 2.0}, only_positive_rewards=False)
    out = {}
    for name, scales in (("plain", {}), ("scaled", {"gap": {"gait_contact": 0.0}, "hurdle": {"gait_contact": 0.5}})):
        cfg = HikingEnvConfig(num_envs=4, num_threads=1, **quiet(**base, category_reward_scales=scales))
        env = HikingEnv(cfg)
        env.set_seed(3)
        env.reset()
        for _ in range(3):
            nxt = act(env)
        ss = env.step_state
        category = np.asarray(ss.tile_category[ss.tile])
        out[name] = (nxt["reward_terms"].to_dict(), nxt["reward"].numpy().ravel(), category, env)
    plain, scaled = out["plain"], out["scaled"]
    cats = list(plain[3].trails.categories)
    np.testing.assert_array_equal(plain[2], scaled[2])
    assert sorted({cats[c] for c in plain[2]}) == ["gap", "hurdle"]  # both kinds of world are there
    scale = np.array([{"gap": 0.0, "hurdle": 0.5}[cats[c]] for c in plain[2]])
    contact = plain[0]["gait_contact"].numpy().ravel()
    assert (contact > 0).all()  # feet on the ground at the clock's stance: the term pays somewhere
    np.testing.assert_allclose(scaled[0]["gait_contact"].numpy().ravel(), contact * scale, rtol=1e-6)
    for term, value in plain[0].items():
        if term != "gait_contact":
            np.testing.assert_allclose(scaled[0][term].numpy(), value.numpy(), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(scaled[1], plain[1] - contact * (1 - scale), rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match=r"category_reward_scales.gap scales \['gait_joint_ref'\], which carry no weight"):
        HikingEnv(HikingEnvConfig(num_envs=2, num_threads=1, **quiet(
            **base, category_reward_scales={"gap": {"gait_joint_ref": 0.0}})))
    with pytest.raises(ValueError, match="category_reward_scales"):
        HikingEnvConfig(category_reward_scales={"gap": {"gait_contact": -1.0}})
