"""The host step's numbers, pinned: short rollouts whose outputs are summarised in a few values
recorded from the step as it was before the step state was shared with the device-resident step
(``legoh_rl/envs/step_state.py``), so that a change that alters the step's numerics fails here.

Each case steps a few worlds with seeded random actions through truncations (short episodes),
falls, a bad action, an explicit partial reset, pushes and the action delay (both switched on
within the rollout), the gait clock's feed-forward and, for the students, the depth camera. The
recorded values are sums over the rollout of each output group (``SUMMARY``): the refactor they
were recorded for reproduced every output tensor bit for bit; the tolerance leaves room only for
another CPU's last-bit differences in MuJoCo's arithmetic over these few steps.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.randomization import DomainRandConfig

_DR = DomainRandConfig(delay_after_global_steps=15, push_interval_s=0.3)  # delay and pushes mid-rollout
CASES = {
    "oracle_h1": dict(robot="h1", mode="oracle", categories=("ditch", "hurdle"), levels=(2, 4), num_envs=4,
                      gait_period=0.8, gait_feedforward=0.4, domain_rand=_DR, episode_length_s=0.5),
    "student_h1": dict(robot="h1", mode="student", categories=("forest", "gap"), levels=(1, 3), num_envs=3,
                       gait_period=0.8, gait_feedforward=0.3, domain_rand=_DR, episode_length_s=0.4,
                       reward_overrides={"feet_in_pit": -1.0, "gait_contact": 0.5, "gait_joint_ref": 0.5}),
    "oracle_g1": dict(robot="g1", mode="oracle", categories=("randommix",), levels=(0, 3), num_envs=4,
                      gait_period=0.7, gait_feedforward=0.5, domain_rand=_DR, episode_length_s=0.6),
    "eval_g1": dict(robot="g1", mode="eval", categories=("ditch", "gap"), levels=(1, 4), num_envs=4,
                    eval_domain_rand=True, domain_rand=_DR, eval_episode_length_s=0.5),
}
STEPS = 40

#: summary value -> the output keys it sums (float64, over the rollout, NaN left out); every
#: observation on its own, at the root (resets and the steps' carried observations) and in "next"
SUMMARY = {
    **{f"{k}{suffix}": [prefix + (k,)] for k in ("proprio", "goal_gps", "waypoint_gps", "scandots", "privileged",
                                                 "expert_goals", "depth")
       for suffix, prefix in (("", ()), ("_next", ("next",)))},
    "reward": [("next", "reward")],
    "metrics": [("next", "episode", k) for k in ("success", "trail_completion", "traverse_rate", "mev", "ttf",
                                                  "time_to_reach", "level", "category")],
    "flags": [("next", k) for k in ("done", "terminated", "truncated", "perception_tick")]
             + [("next", "info", "bad_action"), ("next", "info", "diverged")],
}

EXPECTED = {
    # recorded by summarise() with the step before the shared step state (see the module docstring)
    "oracle_h1": {
        "proprio": 308.23976113881236, "proprio_next": 316.8651293682751, "goal_gps": 1542.0328705236316,
        "goal_gps_next": 1478.7176305875182, "waypoint_gps": 781.5495875664055,
        "waypoint_gps_next": 750.1058358289301, "scandots": 916.589015943202,
        "scandots_next": 927.5479182053678, "privileged": 2082.278913062546,
        "privileged_next": 1973.85546907784, "expert_goals": 489.2753045830177,
        "expert_goals_next": 469.3573775283294, "depth": 0.0, "depth_next": 0.0, "reward": 0.9367506432463415,
        "metrics": 596.5, "flags": 38.0, "reward_terms": -7.994754636735479, "levels": 11.0,
        "global_steps": 40.0, "bad_action_total": 1.0,
    },
    "student_h1": {
        "proprio": 275.04481060026774, "proprio_next": 242.83406007971826, "goal_gps": 1065.8705450594425,
        "goal_gps_next": 1031.8260538578033, "waypoint_gps": 560.1042491547123,
        "waypoint_gps_next": 541.4662613473192, "scandots": 722.1751491918258,
        "scandots_next": 775.181935231667, "privileged": 1682.1801868623588,
        "privileged_next": 1597.3730160752311, "expert_goals": 365.8989313773927,
        "expert_goals_next": 353.0471248913673, "depth": 350940.5014605522, "depth_next": 338609.65663954616,
        "reward": 0.0, "metrics": 262.9144827872515, "flags": 34.0, "reward_terms": -25.290411813377432,
        "levels": 3.0, "global_steps": 40.0, "bad_action_total": 1.0,
    },
    "oracle_g1": {
        "proprio": 248.23580711580144, "proprio_next": 233.9467347017562, "goal_gps": 1751.2655154373497,
        "goal_gps_next": 1660.864636754617, "waypoint_gps": 752.9437876997981,
        "waypoint_gps_next": 713.4314893095288, "scandots": 429.5229193890581,
        "scandots_next": 483.0126630912981, "privileged": 2463.4173540408956,
        "privileged_next": 2343.8822715788847, "expert_goals": 492.98551975119335,
        "expert_goals_next": 467.0021810496546, "depth": 0.0, "depth_next": 0.0, "reward": 0.6554226590596954,
        "metrics": 341.8000000715256, "flags": 38.0, "reward_terms": -25.045703124917146, "levels": 7.0,
        "global_steps": 40.0, "bad_action_total": 1.0,
    },
    "eval_g1": {
        "proprio": 211.719132333963, "proprio_next": 200.40313820872507, "goal_gps": 1120.707565996796,
        "goal_gps_next": 1073.9929128102958, "waypoint_gps": 559.0476711532101,
        "waypoint_gps_next": 533.9073049714789, "scandots": -322.4302974910779,
        "scandots_next": -274.85689084551905, "privileged": 2537.776287093875,
        "privileged_next": 2419.558649709099, "expert_goals": 430.6874193294352,
        "expert_goals_next": 412.8055875813734, "depth": 376301.9912645668, "depth_next": 359034.3079075515,
        "reward": 0.0, "metrics": 602.8093732595444, "flags": 38.0, "reward_terms": -41.18141393959338,
        "levels": 13.0, "global_steps": 40.0, "bad_action_total": 1.0,
    },
}


def summarise(name: str) -> dict[str, float]:
    """The rollout of case ``name`` summarised: each :data:`SUMMARY` value, the sum of every
    weighted reward term, the curriculum's levels and the env's counters at its end."""
    env = HikingEnv(HikingEnvConfig(num_threads=1, seed=5, variants=1, **CASES[name]))
    n = env.batch_size[0]
    td = env.reset()
    gen = torch.Generator().manual_seed(1)
    outs = [td.clone()]
    for t in range(STEPS):
        a = 1.3 * torch.randn(n, env.A, generator=gen)
        if t == 12:
            a[1, 2] = float("nan")  # a bad action
        out, td = env.step_and_maybe_reset(td.set("action", a))
        outs.append(out)
        if t == 20:  # an explicit partial reset of world 0
            outs.append(env.reset(td.clone().set("_reset", torch.arange(n).eq(0)[:, None])))
    total: dict[str, float] = {}
    for name_, keys in SUMMARY.items():
        total[name_] = sum(float(o[key].double().nan_to_num(0.0).sum())
                           for o in outs for key in keys if key in o.keys(True, True))
    total["reward_terms"] = sum(float(v.double().sum()) for o in outs if "next" in o.keys()
                                for v in o["next", "reward_terms"].values())
    total["levels"] = float(env.curriculum.levels.sum())
    total["global_steps"] = float(env.global_steps)
    total["bad_action_total"] = float(env.bad_action_total)
    return total


@pytest.mark.parametrize("name", list(CASES))
def test_the_host_step_reproduces_its_recorded_numbers(name: str) -> None:
    got, want = summarise(name), EXPECTED[name]
    assert got.keys() == want.keys()
    for key, value in want.items():
        assert np.isclose(got[key], value, rtol=1e-6, atol=1e-6), (key, got[key], value)
    assert want["flags"] > 0 and want["metrics"] != 0  # the rollout has episode ends and perception ticks
