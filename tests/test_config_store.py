"""The recipes' env defaults live in HikingEnvConfig alone (legoh_rl/training/config_store.py):
the composed configs carry the dataclass's values, and the recipe yamls set only what they change."""

import dataclasses
import sys
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir

from legoh_rl.envs import HikingEnvConfig
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.envs.sensors import DepthCameraConfig
from legoh_rl.training.builders import env_config
from legoh_rl.training.config_store import RECIPE_ENV_KEYS, env_defaults

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402,F401  (registers the env group)


def composed(name, overrides=()):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=list(overrides))


def test_env_defaults_are_the_dataclass_fields():
    d = env_defaults()
    assert set(d) == set(RECIPE_ENV_KEYS)
    assert d["categories"] == ["randommix", "ditch", "hurdle", "gap", "forest"] and d["levels"] == [0]
    assert d["episode_length_s"] == HikingEnvConfig.episode_length_s == 20.0
    assert d["num_envs"] == 64 and d["feet_edge_from_level"] == 4 and d["reward_overrides"] == {}
    assert d["domain_rand"] is True and d["curriculum"] is True  # switches, not the nested configs
    fields = {f.name for f in dataclasses.fields(HikingEnvConfig)}
    # depth_source: depth_camera.source; action_delay_after_steps: domain_rand.delay_after_global_steps
    assert set(RECIPE_ENV_KEYS) - {"depth_source", "action_delay_after_steps"} <= fields
    assert d["depth_source"] == DepthCameraConfig().source == "auto"
    assert d["action_delay_after_steps"] == DomainRandConfig().delay_after_global_steps == 24 * 8000


def test_action_delay_after_steps_moves_the_delay_onset_of_training():
    """The paper turns the one-step action delay on after 24 x 8000 env steps per world; a run
    shorter than that (every run here) can bring it forward from the recipe."""
    assert env_config(composed("unified").env, "student").domain_rand.delay_after_global_steps == 192_000
    ec = env_config(composed("unified", ["env.action_delay_after_steps=0"]).env, "student")
    assert ec.domain_rand.delay_after_global_steps == 0 and ec.domain_rand.action_delay
    assert ec.domain_rand.friction and ec.domain_rand.push  # the other terms stay as they were
    off = env_config(composed("unified", ["env.domain_rand=false", "env.action_delay_after_steps=0"]).env, "student")
    assert not off.domain_rand.action_delay
    for bad in ("-1", "2.5", "True", "soon"):
        with pytest.raises(ValueError, match=f"env.action_delay_after_steps must be an integer >= 0.*{bad}"):
            env_config(composed("unified", [f"env.action_delay_after_steps={bad}"]).env, "student")


@pytest.mark.parametrize("recipe, num_envs", [("oracle_ppo", 128), ("unified", 32)])
def test_recipe_env_is_the_defaults_plus_its_own_choices(recipe, num_envs):
    env = composed(recipe).env
    expected = {**env_defaults(), "num_envs": num_envs, "reward_overrides": {"alive": 2.0, "termination": -50.0}}
    assert dict(env) == expected
    # the yaml itself repeats no default
    own = yaml.safe_load((RECIPES / "config" / f"{recipe}.yaml").read_text())["env"]
    repeated = {k: v for k, v in own.items() if env_defaults().get(k) == v}
    assert repeated == {}, f"{recipe}.yaml repeats env defaults {repeated}"


def test_every_env_key_is_overridable_and_reaches_the_env_config():
    cfg = composed("oracle_ppo", ["env.levels=[0,2]", "env.category_weights=[1,2,1,1,1]", "env.gait_period=0.8"])
    ec = env_config(cfg.env, "oracle")
    assert ec.levels == (0, 2) and ec.category_weights == (1.0, 2.0, 1.0, 1.0, 1.0) and ec.gait_period == 0.8
    assert ec.num_envs == 128 and ec.cmd_speed == HikingEnvConfig.cmd_speed
    assert ec.depth_camera.source == "auto"  # the depth camera's source: env.depth_source
    assert env_config(composed("oracle_ppo", ["env.depth_source=host"]).env, "student").depth_camera.source == "host"
    with pytest.raises(ValueError, match="depth source must be one of .* got 'gpu'"):
        env_config(composed("oracle_ppo", ["env.depth_source=gpu"]).env, "student")


def test_a_misspelt_env_key_is_an_error():
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException, match="env.levles"):
        composed("oracle_ppo", ["env.levles=[1]"])


def test_an_env_key_added_with_a_plus_or_in_a_yaml_is_refused_not_ignored():
    cfg = composed("oracle_ppo", ["+env.timestep=0.002"])  # hydra accepts a new key; the env would not read it
    with pytest.raises(ValueError, match=r"env.timestep is not a setting of the recipes' env section"):
        env_config(cfg.env, "oracle")
    ec = env_config(composed("oracle_ppo", ["env.pit_depths=[0.1,0.3,0.6,1,1]"]).env, "oracle")
    assert ec.pit_depths == (0.1, 0.3, 0.6, 1.0, 1.0)
