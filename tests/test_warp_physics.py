"""env.physics=warp: MuJoCo Warp (on Warp's CPU device here) against the C MuJoCo backend.

Contact-rich humanoid dynamics drift apart eventually (float32 against float64, and Warp keeps
fewer heightfield contacts per geom pair: docs/history/warp-feasibility.md), so the tests compare
what should agree: outputs of the same state, the fall before contact, a held pose over half a
second, the outcome of a landing, the rewards and depth of the same state, and randomised
parameters reaching the simulation. Tolerances: float32 rounding of the state is ~2e-6; the held
pose measured 1.6e-3 after 25 control steps, a 5 cm landing 2.3e-3 after 50.
"""

import dataclasses
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from torchrl.envs import check_env_specs

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.envs.warp_physics import PER_WORLD_FIELDS, WarpWorlds, import_mujoco_warp, warp_device
from legoh_rl.training.checkpoint import load_checkpoint

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import evaluate as evaluate_recipe  # noqa: E402
import oracle_ppo  # noqa: E402

N = 4
OFF = DomainRandConfig.off()


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def make(physics, mode="oracle", domain_rand=OFF, **kw):
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=N, num_threads=1, physics=physics, mode=mode, seed=3,
                                    domain_rand=domain_rand, **kw))
    env.reset()
    env.start_qpos = env.worlds.home_qpos.copy()  # the spawn states, kept for the tests' resets
    return env


@pytest.fixture(scope="module")
def pair():
    """(C, Warp) envs on the same trails, reset to the same states, randomisation off."""
    return make("mujoco"), make("warp")


def same_start(c, w, lift=0.0):
    q = c.start_qpos.copy()
    q[:, 2] += lift
    c.worlds.reset(None, qpos=q)
    w.worlds.reset(None, qpos=q)


def test_physics_name_is_checked():
    with pytest.raises(ValueError, match=r"unknown physics 'bullet'; valid: \['mujoco', 'warp'\]"):
        HikingEnvConfig(physics="bullet")


def test_missing_mujoco_warp_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco_warp", None)  # `import mujoco_warp` raises ImportError
    with pytest.raises(ImportError, match=r"mujoco_warp is not installed.*pip install 'legoh-rl\[gpu\]'"):
        import_mujoco_warp()


def test_warp_device_names():
    assert warp_device("cpu") == "cpu"
    assert warp_device("cuda") == "cuda:0"
    assert warp_device(torch.device("cuda:1")) == "cuda:1"
    with pytest.raises(ValueError, match="cpu or cuda devices, got 'meta'"):
        warp_device("meta")


def test_same_state_gives_the_same_outputs_and_observations(pair):
    c, w = pair
    same_start(c, w)
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 1e-5  # float32 rounding of the state
    for name in ("xpos", "xquat", "cam_xpos", "cam_xmat"):
        assert np.abs(getattr(w.worlds, name) - getattr(c.worlds, name)).max() < 1e-5, name
    td_c, td_w = c.reset(), w.reset()
    for key in ("proprio", "scandots", "privileged", "goal_gps"):
        assert torch.allclose(td_c[key], td_w[key], atol=1e-4), key


def test_fall_before_contact_matches_to_float32_rounding(pair):
    c, w = pair
    same_start(c, w, lift=0.3)
    for _ in range(8):  # 0.16 s: 0.13 m of free fall, no contact yet
        c.worlds.step()
        w.worlds.step()
    assert (c.worlds.qpos[:, 2] < c.start_qpos[:, 2] + 0.25).all()  # it did fall
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 1e-4


def test_held_pose_stays_within_5mm(pair):
    c, w = pair
    same_start(c, w)
    for _ in range(25):  # 0.5 s standing on the PD targets of the default pose
        c.worlds.step()
        w.worlds.step()
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 5e-3
    assert c.worlds.diverged_total == w.worlds.diverged_total == 0


def test_landing_ends_standing_at_the_same_height(pair):
    c, w = pair
    same_start(c, w, lift=0.05)
    for _ in range(50):
        c.worlds.step()
        w.worlds.step()
    for worlds in (c.worlds, w.worlds):
        assert (worlds.qpos[:, 2] > c.start_qpos[:, 2] - 0.1).all()  # standing in both
    assert np.abs(w.worlds.qpos[:, 2] - c.worlds.qpos[:, 2]).max() < 0.01


def test_same_actions_give_the_same_rewards_and_terminations(pair):
    c, w = pair
    td_c, td_w = c.reset(), w.reset()
    same_start(c, w)
    action = 0.3 * torch.randn(N, c.A, generator=torch.Generator().manual_seed(0))
    for _ in range(5):
        td_c = c.step(td_c.set("action", action))["next"]
        td_w = w.step(td_w.set("action", action))["next"]
        assert torch.allclose(td_c["reward"], td_w["reward"], atol=0.02, rtol=0.01)
        assert torch.equal(td_c["done"], td_w["done"])


def test_depth_of_the_same_scene():
    c, w = make("mujoco", mode="student"), make("warp", mode="student")
    same_start(c, w)
    c._render_depth(np.ones(N, dtype=bool))
    w._render_depth(np.ones(N, dtype=bool))
    diff = np.abs(w.depth - c.depth)
    assert (diff < 1e-3).mean() > 0.99 and diff.max() < 0.05  # a pixel on an edge may flip


def test_randomised_parameters_reach_the_simulation():
    """Mass, CoM and motor strength drawn per world: Warp follows C, and ignoring them would not."""
    on = dataclasses.replace(OFF, base_mass=True, base_com=True, motor_strength=True)
    c, w, plain = make("mujoco", domain_rand=on), make("warp", domain_rand=on), make("mujoco")
    assert np.allclose(c.randomizer.privileged(), w.randomizer.privileged())
    assert np.ptp(c.randomizer.motor_strength[:, 0]) > 0.05  # the worlds differ
    q = c.start_qpos.copy()
    for env in (c, w, plain):
        env.worlds.reset(None, qpos=q)
    for _ in range(25):
        for env in (c, w, plain):
            env.worlds.step()
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 5e-3
    assert np.abs(plain.worlds.qpos - c.worlds.qpos).max() > 2e-2
    with pytest.raises(ValueError, match=r"keeps \[.*'geom_friction'.*\] per world, not 'geom_size'"):
        w.worlds.per_world("geom_size")
    assert "body_mass" in PER_WORLD_FIELDS


def test_a_diverged_world_is_reset_alone_and_counted(pair):
    _, w = pair
    worlds = w.worlds
    worlds.reset()
    home = worlds.home_qpos.copy()
    worlds.step()
    before = worlds.qpos.copy()
    worlds.qvel[1, 0] = np.nan
    total = worlds.diverged_total
    bad = worlds.step()
    assert bad.tolist() == [False, True, False, False] and worlds.diverged_total == total + 1
    assert np.allclose(worlds.qpos[1], home[1], atol=1e-5) and worlds.time[1] == 0.0
    assert not np.allclose(worlds.qpos[0], before[0])  # the others stepped on


def test_contact_buffer_overflow_resets_the_world(pair):
    c, _ = pair
    worlds = WarpWorlds(c.built, 2, num_threads=1, nconmax=1, njmax=320)
    worlds.reset(None, qpos=c.start_qpos[:2])
    bad = np.zeros(2, dtype=bool)
    for _ in range(10):  # the feet land with more than one contact each
        bad |= worlds.step()
    assert bad.all() and worlds.overflow_total >= 2 and worlds.diverged_total >= worlds.overflow_total
    assert np.isfinite(worlds.qpos).all()
    with pytest.raises(ValueError, match="nconmax must be >= 1, got 0"):
        WarpWorlds(c.built, 1, nconmax=0)


def test_world_data_for_the_renderer(pair):
    c, w = pair
    same_start(c, w)
    dc, dw = mujoco.MjData(c.built.model), mujoco.MjData(c.built.model)
    c.worlds.world_data(2, dc)
    w.worlds.world_data(2, dw)
    assert np.abs(dc.xpos - dw.xpos).max() < 1e-5 and np.abs(dc.cam_xpos - dw.cam_xpos).max() < 1e-5


def test_env_specs_on_warp():
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=2, num_threads=1, physics="warp"))
    check_env_specs(env, seed=0)


def test_oracle_recipe_trains_and_evaluate_runs_on_warp(tmp_path):
    """``env.physics=warp`` from the command line of oracle_ppo.py and ``physics=warp`` of evaluate.py."""
    env = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1", "env.physics=warp",
           "logger.backend=csv"]
    oracle_ppo.train(cfg_of("oracle_ppo", env + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                 "ppo.num_epochs=1", f"checkpoint.dir={tmp_path / 'ck'}"]))
    state = load_checkpoint(tmp_path / "ck" / "last.pt")
    assert state["config"]["env"]["physics"] == "warp" and state["frames"] == 32
    out = evaluate_recipe.evaluate(cfg_of("evaluate", [
        f"checkpoint={tmp_path / 'ck' / 'last.pt'}", "physics=warp", "categories=[randommix]", "levels=[0]",
        "robots_per_cell=2", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}", "video=false",
        "logger.backend=csv"]))
    assert len(out["episodes"]) == 2
    with pytest.raises(ValueError, match="unknown physics 'gpu'"):
        evaluate_recipe.evaluate(cfg_of("evaluate", ["checkpoint=zero", "physics=gpu", "categories=[randommix]",
                                                     "levels=[0]", "robots_per_cell=1", "variants=1", "video=false",
                                                     f"output_dir={tmp_path / 'bad'}", "logger.backend=csv"]))
