"""Gymnasium's vector API on the batched env: ``gymnasium.make_vec(id, vectorization_mode=
"vector_entry_point")`` (legoh_rl.envs.gym_env.HikingVectorEnv).

Gymnasium 1.4 has no checker for vector envs, so these tests hold the env to what its own vector
envs do: batched spaces built by ``batch_space``, observations inside them at reset and at every
step (``Space.contains``, per world through ``iterate``), the declared SAME_STEP autoreset on a
world made to fall and on truncations, and, for one world, the same data as Gymnasium's own
``SyncVectorEnv`` over the single-world env (``check_environments_match`` and an exact
comparison of everything, infos included).
"""

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_match import check_environments_match
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, iterate
from scenes import BoxScene

import legoh_rl.envs  # noqa: F401  (registers the ids)
from legoh_rl.envs.gym_env import HikingVectorEnv

IDS = ("LegoH/Hike-H1-v0", "LegoH/Hike-G1-v0", "LegoH/HikeDepth-H1-v0", "LegoH/HikeDepth-G1-v0")


def _make_vec(env_id="LegoH/Hike-H1-v0", n=3, **kw):
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", trails=BoxScene(),
                        num_threads=1, **kw)


def _assert_in_spaces(envs, obs):
    assert envs.observation_space.contains(obs), {k: (v.shape, v.dtype) for k, v in obs.items()}
    for k, v in obs.items():
        assert v.dtype == np.float32 and v.shape == envs.observation_space[k].shape, k
    for world in iterate(envs.observation_space, obs):
        assert envs.single_observation_space.contains(world)


def _tip_over(envs, world: int) -> None:
    """Hand-made state: world ``world`` rolled 90 degrees about its heading (a fall)."""
    worlds = envs.unwrapped.env.worlds
    qpos = worlds.qpos[[world]].copy()
    qpos[0, 3:7] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]
    worlds.reset(np.array([world]), qpos=qpos)


def test_every_id_has_a_batched_vector_entry_point():
    for env_id in IDS:
        assert gym.spec(env_id).vector_entry_point == "legoh_rl.envs.gym_env:HikingVectorEnv"
    envs = _make_vec("LegoH/HikeDepth-H1-v0", n=2)  # student mode: depth in the observations
    assert isinstance(envs, HikingVectorEnv) and isinstance(envs, VectorEnv)
    assert envs.unwrapped.env.batch_size == (2,)  # one env of two worlds, not two envs
    assert envs.observation_space["depth"].shape == (2, 1, 64, 64)
    obs, infos = envs.reset(seed=0)
    _assert_in_spaces(envs, obs)
    assert infos == {}
    envs.close()


def test_make_vec_spaces_steps_and_same_step_autoreset():
    envs = _make_vec(n=3, max_episode_steps=4)
    n, a = 3, envs.unwrapped.env.A
    assert envs.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert envs.metadata["render_fps"] == pytest.approx(50.0)
    assert envs.observation_space == batch_space(envs.single_observation_space, n)
    assert envs.action_space == batch_space(envs.single_action_space, n)
    assert envs.action_space.shape == (n, a) and envs.action_space.dtype == np.float32
    assert envs.observation_space["proprio"].shape == (n, 37)
    obs, _ = envs.reset(seed=0)
    _assert_in_spaces(envs, obs)
    again, _ = envs.reset(seed=0)  # the seed fixes the spawns and the randomisation
    for k in obs:
        np.testing.assert_array_equal(obs[k], again[k])

    # step 1: world 1 falls (hand-made state) and is reset within the same step
    _tip_over(envs, 1)
    envs.action_space.seed(0)
    actions = 0.3 * envs.action_space.sample()
    obs, rewards, terminations, truncations, infos = envs.step(actions)
    _assert_in_spaces(envs, obs)
    assert rewards.shape == (n,) and rewards.dtype == np.float64
    assert terminations.dtype == truncations.dtype == np.bool_
    assert terminations.tolist() == [False, True, False] and not truncations.any()
    assert infos["_final_obs"].tolist() == [False, True, False] and infos["_final_info"].tolist() == [False, True, False]
    assert infos["final_obs"][0] is None and infos["final_obs"][2] is None
    last = infos["final_obs"][1]
    assert envs.single_observation_space.contains(last)
    assert abs(last["proprio"][3]) > 1.0  # the fallen world's last roll, rad
    assert abs(obs["proprio"][1, 3]) < 0.2  # its new episode: upright on its spawn
    prev_action = slice(5 + 2 * a, 5 + 3 * a)
    np.testing.assert_allclose(last["proprio"][prev_action], actions[1], rtol=1e-6)
    assert not obs["proprio"][1, prev_action].any()  # a new episode has no previous action
    np.testing.assert_allclose(obs["proprio"][0, prev_action], actions[0], rtol=1e-6)
    final = infos["final_info"]
    assert final["_episode"].tolist() == [False, True, False] and final["episode"]["success"][1] == 0.0
    assert final["episode"]["ttf"][1] == pytest.approx(0.02)  # fell after one 20 ms step
    assert infos["_reward_terms"].tolist() == [True, False, True]
    assert final["reward_terms"]["orientation"][1] < infos["reward_terms"]["orientation"][0] <= 0.0

    # steps 2-4: worlds 0 and 2 reach max_episode_steps=4 at step 4; world 1 one step later
    for step in range(2, 6):
        obs, rewards, terminations, truncations, infos = envs.step(np.zeros((n, a), np.float32))
        _assert_in_spaces(envs, obs)
        assert not terminations.any()
        expect = {4: [True, False, True], 5: [False, True, False]}.get(step, [False, False, False])
        assert truncations.tolist() == expect, step
        if any(expect):
            assert infos["_final_obs"].tolist() == expect
            assert (infos["final_info"]["episode"]["ttf"][np.array(expect)] == pytest.approx(0.08))
        else:
            assert "final_obs" not in infos

    # a partial reset through options, as Gymnasium's vector envs take it
    before, *_ = envs.step(np.zeros((n, a), np.float32))
    obs, infos = envs.reset(options={"reset_mask": np.array([False, True, False])})
    for k in obs:
        np.testing.assert_array_equal(obs[k][[0, 2]], before[k][[0, 2]])
    assert not obs["proprio"][1, prev_action].any() and infos == {}
    envs.close()


def test_vector_env_bad_input_names_the_value():
    envs = _make_vec(n=2)
    envs.reset(seed=0)
    a = envs.unwrapped.env.A
    with pytest.raises(ValueError, match=rf"actions must have shape \(2, {a}\) \(num_envs, num_actions\), got \(3, {a}\)"):
        envs.step(np.zeros((3, a), np.float32))
    with pytest.raises(ValueError, match=r"reset_mask'\] must be a \(2,\) bool numpy array"):
        envs.reset(options={"reset_mask": np.array([1, 0])})
    with pytest.raises(ValueError, match="at least one True"):
        envs.reset(options={"reset_mask": np.zeros(2, bool)})
    with pytest.raises(ValueError, match=r"seed must be an int or None .* got \[0, 1\]"):
        envs.reset(seed=[0, 1])
    envs.close()
    with pytest.raises(ValueError, match="max_episode_steps must be a positive integer or None, got 0"):
        HikingVectorEnv(num_envs=2, max_episode_steps=0, trails=BoxScene(), num_threads=1)
    with pytest.raises(ValueError, match="num_envs must be a positive integer, got 0"):
        HikingVectorEnv(num_envs=0, trails=BoxScene(), num_threads=1)


def _assert_same(x, y, path="") -> None:
    """Exact equality of nested step data (dicts, object arrays, arrays: dtypes and NaNs too)."""
    if isinstance(x, dict):
        assert isinstance(y, dict) and x.keys() == y.keys(), (path, sorted(x), sorted(y))
        for k in x:
            _assert_same(x[k], y[k], f"{path}/{k}")
    elif isinstance(x, np.ndarray) and x.dtype == object:
        assert y.dtype == object and x.shape == y.shape, path
        for i, (p, q) in enumerate(zip(x, y, strict=True)):
            _assert_same(p, q, f"{path}[{i}]")
    elif isinstance(x, np.ndarray):
        assert isinstance(y, np.ndarray) and x.dtype == y.dtype and x.shape == y.shape, (path, x.dtype, y.dtype)
        np.testing.assert_array_equal(x, y, err_msg=path)
    else:
        assert x == y, path


def test_one_world_matches_gymnasiums_sync_vector_env():
    """N = 1: the batched vector env gives what Gymnasium's SyncVectorEnv (SAME_STEP) gives over
    the single-world env, through two episode ends (0.1 s = 5-step episodes)."""
    kw = dict(trails=BoxScene(), num_threads=1, episode_length_s=0.1)
    batched = gym.make_vec("LegoH/Hike-H1-v0", num_envs=1, vectorization_mode="vector_entry_point", **kw)
    sync = gym.make_vec("LegoH/Hike-H1-v0", num_envs=1, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}, **kw)
    # Gymnasium's own check (its info comparison treats NaN != NaN, and time_to_reach is NaN for
    # an episode that did not reach P_B: keys here, values exactly below)
    check_environments_match(batched, sync, num_steps=7, seed=3, info_comparison="keys-equivalence")
    for env in (batched, sync):
        env.reset(seed=5)
        env.action_space.seed(5)
    ends = 0
    for _ in range(11):
        action = batched.action_space.sample()
        out_b, out_s = batched.step(action), sync.step(action)
        for x, y, name in zip(out_b, out_s, ("obs", "reward", "terminated", "truncated", "infos"), strict=True):
            _assert_same(x, y, name)
        ends += int(out_b[2][0] or out_b[3][0])
    assert ends == 2
    batched.close()
    sync.close()


def test_vector_render_frames_per_world():
    envs = _make_vec(n=2)
    envs.reset(seed=0)
    with pytest.warns(UserWarning, match="without a render mode"):
        assert envs.render() is None
    envs.close()
    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8).close()
    except Exception as err:  # no off-screen OpenGL (what `make gl` installs)
        pytest.skip(f"no off-screen OpenGL context for MuJoCo ({type(err).__name__}: {err})")
    envs = _make_vec(n=2, render_mode="rgb_array", width=64, height=48)
    envs.reset(seed=0)
    frames = envs.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    assert all(f.shape == (48, 64, 3) and f.dtype == np.uint8 for f in frames)
    assert frames[0].reshape(-1, 3).std(0).max() > 10.0  # a scene, not a blank frame
    envs.close()
