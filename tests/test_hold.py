"""Held worlds (``HikingEnv.hold``): an evaluation's finished worlds stop costing a step.

A held world's simulation stays where it is (C MuJoCo), it ends no episode, takes no depth frame
and never ticks; every other world steps exactly as it would without the hold, and an evaluation
that holds its finished worlds records the same episodes as one that steps them on."""

from pathlib import Path

import numpy as np
import pytest
import torch
from scenes import BoxScene
from tensordict import TensorDict

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.training.evaluation import EvalProtocol, run_protocol
from legoh_rl.training.policies import load_policy
from legoh_rl.transforms import PerceptionHold

ROOT = Path(__file__).resolve().parents[1]


def make(n=4, mode="oracle", **kw):
    cfg = HikingEnvConfig(robot="h1", num_envs=n, mode=mode, num_threads=1, spawn_jitter_xy=0.0,
                          spawn_jitter_yaw=0.0, domain_rand=DomainRandConfig.off(), **kw)
    env = HikingEnv(cfg, trails=BoxScene())
    env.set_seed(0)
    return env


def step(env, action):
    return env.step(TensorDict({"action": action}, batch_size=env.batch_size))["next"]


def test_batched_worlds_step_only_the_active_worlds_and_leave_the_others_exact():
    held_env, free_env = make(), make()
    held_env.reset(), free_env.reset()
    worlds, twin = held_env.worlds, free_env.worlds
    rng = np.random.default_rng(1)
    targets = np.asarray(twin.built.robot.default_joint_pos) + 0.2 * rng.standard_normal((3, 4, twin.built.actuator_ids.size))
    active = np.array([True, False, True, False])
    for t in targets:
        worlds.set_joint_targets(t)
        twin.set_joint_targets(t)
        before = worlds.qpos.copy(), worlds.qvel.copy()
        worlds.step(active)
        twin.step()
        np.testing.assert_array_equal(worlds.qpos[~active], before[0][~active])  # held still, to the bit
        np.testing.assert_array_equal(worlds.qvel[~active], before[1][~active])
        np.testing.assert_array_equal(worlds.qpos[active], twin.qpos[active])  # the rest as a full step
        np.testing.assert_array_equal(worlds.qvel[active], twin.qvel[active])
    assert not np.array_equal(worlds.qpos[0], held_env.worlds.home_qpos[0])  # the active ones did move
    worlds.step(np.zeros(4, dtype=bool))  # nothing active: nothing moves
    with pytest.raises(ValueError, match=r"active must be a \(4,\) bool mask, got shape \(3,\)"):
        worlds.step(np.ones(3, dtype=bool))


@pytest.mark.parametrize("mode", ["oracle", "student"])
def test_a_held_world_stands_still_ends_nothing_and_never_ticks_while_the_others_step_as_before(mode):
    held_env, free_env = make(mode=mode), make(mode=mode)
    held_env.reset(), free_env.reset()
    held_env.hold([1])
    assert held_env.held.tolist() == [False, True, False, False]
    qpos_1 = held_env.worlds.qpos[1].copy()
    torch.manual_seed(0)
    rendered = []
    camera = held_env._render_depth
    held_env._render_depth = lambda which: (rendered.append(which.copy()), camera(which))[1]
    free_ended = False
    for _ in range(60):  # past perception ticks (every 5th step) and the fall of a flailing robot
        action = 3.0 * torch.randn(4, held_env.A)
        a, b = step(held_env, action), step(free_env, action)
        free_ended |= bool(b["done"][1].item())
        np.testing.assert_array_equal(held_env.worlds.qpos[1], qpos_1)
        assert not a["done"][1].item() and not a["terminated"][1].item() and not a["truncated"][1].item()
        assert not a["perception_tick"][1].item()
        for key in ("proprio", "scandots", "reward", "done", "perception_tick") + (("depth",) if mode == "student" else ()):
            torch.testing.assert_close(a[key][[0, 2, 3]], b[key][[0, 2, 3]], rtol=0, atol=0)
    assert free_ended  # without the hold, its episode would have ended
    if mode == "student":
        assert rendered and not any(w[1] for w in rendered)  # no depth frame was cast for it
        assert any(w[0] for w in rendered)
    held_env.reset()  # a reset releases every world
    assert not held_env.held.any()


def test_a_partial_reset_releases_only_its_worlds_and_bad_worlds_are_refused():
    env = make()
    env.reset()
    env.hold(np.array([True, True, False, False]))
    reset = torch.tensor([True, False, False, False])
    env.reset(TensorDict({"_reset": reset[:, None]}, batch_size=env.batch_size))
    assert env.held.tolist() == [False, True, False, False]
    with pytest.raises(ValueError, match=r"world indices must lie in \[0, 4\), got \[4\]"):
        env.hold([4])
    with pytest.raises(ValueError, match="hold needs the worlds to hold"):
        env.hold(None)
    with pytest.raises(ValueError, match=r"a world mask must have shape \(4,\), got \(2,\)"):
        env.hold(np.array([True, False]))


def _count_perception(policy) -> list[int]:
    """Hook the student's perception (inside its PerceptionHold): the batch size of every call."""
    calls = []
    holds = [m for m in policy.modules() if isinstance(m, PerceptionHold)]
    assert holds, "the student policy has no PerceptionHold"
    holds[0].perception.register_forward_pre_hook(
        lambda module, args, kwargs: calls.append(int((args[0] if args else kwargs["tensordict"]).numel())),
        with_kwargs=True)
    return calls


def test_an_evaluation_that_holds_its_finished_worlds_records_the_same_episodes():
    """The stage-5 oracle's student on level-4 Ditch and Gap, where it falls within ~6 s, the Ditch pair
    first (grid 9301): the Ditch worlds are held while the Gap worlds walk on. Its perception runs
    on the ticking worlds only and the held ones tick no more: fewer perception samples, in
    smaller batches whose rounding may differ in the last bits, so the episodes agree to float32
    precision (the other worlds' steps are exact: the env tests above)."""
    protocol = EvalProtocol(categories=("gap", "ditch"), levels=(4,), robots_per_cell=2, trajectories=4)
    runs = {}
    for hold in (False, True):
        env, policy, _ = load_policy(str(ROOT / "checkpoints" / "student_h1_real_pits.pt"), protocol, variants=1, seed=9301,
                                     num_threads=1)
        calls = _count_perception(policy)
        result = run_protocol(env, policy, protocol, hold_finished=hold)
        runs[hold] = (result.episodes, sum(calls), env.base_env.global_steps, result.trajectories,
                      env.base_env.held.copy())
        env.close()
    (free, free_calls, free_steps, free_paths, _), (held, held_calls, held_steps, held_paths, held_at_end) = \
        runs[False], runs[True]
    assert len(held) == 4 and held_at_end.sum() == 4  # every world finished, and was held then
    assert sorted(e["ttf"] for e in held)[0] < sorted(e["ttf"] for e in held)[-1]  # some were held for a while
    assert held_steps == free_steps  # the run lasts as long as its longest episode either way
    for a, b in zip(held, free, strict=True):
        assert (a["category"], a["level"], a["success"]) == (b["category"], b["level"], b["success"])
        np.testing.assert_allclose([a[k] for k in ("trail_completion", "mev", "ttf")],
                                   [b[k] for k in ("trail_completion", "mev", "ttf")], rtol=1e-4)
    for w in free_paths:
        np.testing.assert_allclose(held_paths[w], free_paths[w], atol=1e-4)
    assert 0 < held_calls < free_calls  # the finished worlds' perception stopped
