"""The recipes' env and ppo sections are their dataclasses (legoh_rl/training/config_store.py):
the composed configs carry every field's default, every field (nested sections included) is
reachable from each training recipe, the recipe yamls set only what they change, the shared
sections are written once, and configs recorded in the old layout read in today's."""

import dataclasses
import sys
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from legoh_rl.envs import HikingEnvConfig
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.kinds import Choice, Flag, Integer, ListOf, MapOf, Name, Number, OneOf, field_kind
from legoh_rl.objectives.ppo import PPOConfig
from legoh_rl.training.builders import policy_env_kwargs
from legoh_rl.training.checkpoint import load_checkpoint
from legoh_rl.training.config_store import (
    SET_BY_RECIPE,
    env_config,
    env_defaults,
    ppo_config,
    ppo_defaults,
    upgrade_recorded_config,
)

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402,F401  (registers the env and ppo groups)

TRAINING = ("oracle_ppo", "unified")
MODE = {"oracle_ppo": "oracle", "unified": "student"}
PPO_OWN = {"oracle_ppo": (), "unified": ("weight",)}


def composed(name, overrides=()):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=list(overrides))


def leaves(node: dict, prefix: str = "") -> dict:
    """``{dotted key: value}`` of a nested mapping's leaves (``reward_overrides`` as one leaf)."""
    out = {}
    for key, value in node.items():
        if isinstance(value, dict) and key != "reward_overrides":
            out.update(leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def kind_of(cls, dotted: str):
    """The kind of field ``dotted`` (``domain_rand.push``) of dataclass ``cls``."""
    head, _, rest = dotted.partition(".")
    f = {f.name: f for f in dataclasses.fields(cls)}[head]
    return kind_of(type(f.default_factory()), rest) if rest else field_kind(f)


def another_value(kind, default):
    """A valid value of ``kind`` other than ``default``."""
    if isinstance(kind, Flag):
        return True if default is None else not default
    if isinstance(kind, Integer):
        return kind.minimum + 1 if default is None else default + 1 if kind.maximum is None or default < kind.maximum else default - 1
    if isinstance(kind, Number):
        value = 0.5 if default is None else default * 0.5 if default else 0.25
        return value if kind.accepts(value) else (kind.low + kind.high) / 2
    if isinstance(kind, Choice):
        return next(c for c in kind.options if c != default)
    if isinstance(kind, ListOf):
        if kind.length is not None:
            return [default[0] - 0.1, default[1]]
        if default is None:
            return [0.5] * 5  # category_weights (one per default category), pit_depths
        if isinstance(kind.item, Choice):
            return [kind.item.options[-1]]
        return [1]  # levels
    if isinstance(kind, MapOf):
        return {"alive": 3.0}
    if isinstance(kind, OneOf):
        return ["push"]  # eval_domain_rand
    if isinstance(kind, Name):
        return "x"
    raise AssertionError(kind)


def override(key, value) -> str:
    """``key=value`` in hydra's override grammar."""
    def fmt(v):
        if v is None:
            return "null"
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, list | tuple):
            return "[" + ",".join(fmt(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ",".join(f"{k}:{fmt(x)}" for k, x in v.items()) + "}"
        return str(v)
    return f"{key}={fmt(value)}"


def test_the_groups_are_the_dataclasses_fields():
    env = env_defaults()
    assert set(env) == {f.name for f in dataclasses.fields(HikingEnvConfig)} - set(SET_BY_RECIPE)
    assert env["categories"] == ["randommix", "ditch", "hurdle", "gap", "forest"] and env["levels"] == [0]
    assert env["timestep"] == 0.005 and env["decimation"] == 4 and env["freeze_ankle_roll"] is False
    assert env["domain_rand"]["enabled"] is True and env["domain_rand"]["delay_after_global_steps"] == 24 * 8000
    assert env["domain_rand"]["friction_range"] == [0.6, 2.0] and env["curriculum"] == {"enabled": True, "up": 0.8,
                                                                                        "down": 0.4}
    assert env["depth_camera"]["source"] == "auto" and env["depth_camera"]["height"] == 64
    assert ppo_defaults() == {f.name: f.default for f in dataclasses.fields(PPOConfig)}
    assert ppo_defaults()["min_lr"] == 1e-5 and ppo_defaults()["max_lr"] == 1e-2 and ppo_defaults()["clip_value"]


@pytest.mark.parametrize("recipe", TRAINING)
def test_every_field_is_reachable_from_the_recipe(recipe):
    """Every leaf of the env and ppo groups, set to another valid value on the command line,
    reaches the dataclass the recipe builds (one command line sets them all; the evaluation-only
    ``eval_domain_rand`` is built in eval mode, which refuses the training's ``pit_depths``)."""
    values = {}
    for section, cls, defaults in (("env", HikingEnvConfig, env_defaults()), ("ppo", PPOConfig, ppo_defaults())):
        for dotted, default in leaves(defaults).items():
            values[f"{section}.{dotted}"] = another_value(kind_of(cls, dotted), default)
    values["env.category_weights"] = [0.5] * len(values["env.categories"])  # one per category
    assert values["env.physics"] == "warp" and values["env.gait_period"] > 0  # what resident, gait_feedforward need
    eval_only = {"env.eval_domain_rand": values.pop("env.eval_domain_rand")}
    cfg = composed(recipe, [override(k, v) for k, v in values.items()])
    built = {"env": dataclasses.asdict(env_config(cfg.env, MODE[recipe])),
             "ppo": dataclasses.asdict(ppo_config(cfg.ppo, PPO_OWN[recipe]))}
    cfg = composed(recipe, [override(k, v) for k, v in eval_only.items()])
    built_eval = {"env": dataclasses.asdict(env_config(cfg.env, "eval"))}
    for key, value in {**values, **eval_only}.items():
        have = built_eval if key in eval_only else built
        for part in key.split("."):
            have = have[part]
        have = list(have) if isinstance(have, tuple) else have
        if isinstance(value, dict):  # merged into the recipe's own reward_overrides
            have = {k: have[k] for k in value}
        assert have == value, key
    assert len(values) + len(eval_only) == len(leaves(env_defaults())) + len(ppo_defaults()) > 60


@pytest.mark.parametrize("recipe, num_envs", [("oracle_ppo", 128), ("unified", 32)])
def test_recipe_sections_are_the_defaults_plus_its_own_choices(recipe, num_envs):
    cfg = OmegaConf.to_container(composed(recipe), resolve=True)
    assert cfg["env"] == {**env_defaults(), "num_envs": num_envs, "reward_overrides": {"alive": 2.0, "termination": -50.0}}
    own = yaml.safe_load((RECIPES / "config" / f"{recipe}.yaml").read_text())
    repeated = {k: v for k, v in own["env"].items() if env_defaults().get(k) == v}
    assert repeated == {}, f"{recipe}.yaml repeats env defaults {repeated}"
    repeated = {k: v for k, v in (own.get("ppo") or {}).items() if ppo_defaults().get(k) == v}
    assert repeated == {}, f"{recipe}.yaml repeats PPOConfig defaults {repeated}"
    shared = yaml.safe_load((RECIPES / "config" / "shared" / "training.yaml").read_text())
    for section, values in shared.items():  # in the recipe's config, not repeated in its yaml
        if isinstance(values, dict):
            assert {k: cfg[section][k] for k in values} == values
            assert not set(values) & set(own.get(section) or {}), (recipe, section)
        else:
            assert cfg[section] == values and section not in own


def test_the_ppo_settings_of_each_recipe():
    """Hand-checked: the numbers each recipe trained with before PPO's section was PPOConfig's
    (oracle_ppo: rsl_rl's; unified: lr 3e-4, 2 x 2; both clamp the adaptive lr to [1e-5, 1e-2])."""
    oracle = ppo_config(composed("oracle_ppo").ppo)
    assert (oracle.learning_rate, oracle.num_epochs, oracle.num_minibatches, oracle.min_lr, oracle.max_lr) == (
        1e-3, 5, 4, 1e-5, 1e-2)
    assert (oracle.clip_epsilon, oracle.entropy_coeff, oracle.gamma, oracle.lmbda, oracle.desired_kl) == (
        0.2, 0.01, 0.99, 0.95, 0.01)
    unified = ppo_config(composed("unified").ppo, PPO_OWN["unified"])
    assert (unified.learning_rate, unified.num_epochs, unified.num_minibatches, unified.min_lr, unified.max_lr) == (
        3e-4, 2, 2, 1e-5, 1e-2)
    assert unified.clip_value and unified.critic_coeff == 1.0 and unified.loss_critic_type == "l2"
    assert composed("unified").ppo.weight == 1.0
    with pytest.raises(ValueError, match=r"ppo: PPOConfig needs 0 < min_lr <= learning_rate <= max_lr"):
        ppo_config(composed("unified", ["ppo.learning_rate=0.05"]).ppo, PPO_OWN["unified"])


@pytest.mark.parametrize("experiment, mode, expected", [
    # hand-checked against the code before the env section was HikingEnvConfig's
    ("student_h1_randommix", "student", {"categories": ("randommix",), "levels": (0, 1), "variants": 4, "cmd_speed": 0.5,
                                         "curriculum": {"enabled": False, "up": 0.8, "down": 0.4}}),
    ("oracle_h1_trails", "oracle", {"num_envs": 256, "decimation": 4, "timestep": 0.005}),
    ("oracle_g1_randommix", "oracle", {"robot": "g1", "gait_amplitude": 0.45, "gait_period": 0.8}),
])
def test_experiments_build_the_settings_they_built_before(experiment, mode, expected):
    recipe = OmegaConf.load(RECIPES / "config" / "experiment" / f"{experiment}.yaml").recipe
    cfg = composed(recipe, [f"experiment={experiment}"])
    fixed = {"gait_period": 0.8} if recipe == "unified" and cfg.env.reward_overrides.get("gait_contact") else {}
    ec = dataclasses.asdict(env_config(cfg.env, mode, **fixed))
    assert {k: ec[k] for k in expected} == expected
    assert ec["domain_rand"] == dataclasses.asdict(DomainRandConfig())


def test_switches_and_nested_settings():
    ec = env_config(composed("unified", ["env.domain_rand.enabled=false"]).env, "student")
    assert not any(getattr(ec.domain_rand, t) for t in ("friction", "push", "action_delay"))
    assert env_config(composed("unified").env, "student").domain_rand.delay_after_global_steps == 192_000
    ec = env_config(composed("unified", ["env.domain_rand.delay_after_global_steps=0"]).env, "student")
    assert ec.domain_rand.delay_after_global_steps == 0 and ec.domain_rand.action_delay and ec.domain_rand.friction
    assert env_config(composed("oracle_ppo", ["env.categories=gap"]).env, "oracle").categories == ("gap",)
    with pytest.raises(ValueError, match=r"env.curriculum must be a section .* got False \(env.curriculum.enabled=false"):
        env_config(composed("oracle_ppo", ["env.curriculum=false"]).env, "oracle")
    with pytest.raises(ValueError, match="env.depth_camera.source: unknown depth source 'gpu'"):
        env_config(composed("oracle_ppo", ["env.depth_camera.source=gpu"]).env, "student")
    with pytest.raises(ValueError, match="env: gait_feedforward=0.5 needs a gait clock"):
        env_config(composed("oracle_ppo", ["env.gait_feedforward=0.5"]).env, "oracle")


def test_a_misspelt_or_added_env_key_is_refused():
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException, match="env.levles"):
        composed("oracle_ppo", ["env.levles=[1]"])
    cfg = composed("oracle_ppo", ["+env.timestepp=0.002"])  # hydra accepts a new key; the dataclass does not
    with pytest.raises(ValueError, match=r"env has no setting 'timestepp'"):
        env_config(cfg.env, "oracle")
    with pytest.raises(ValueError, match=r"env.device='cuda' is not a setting"):
        env_config({**OmegaConf.to_container(composed("oracle_ppo").env), "device": "cuda"}, "oracle")


OLD_ENV = {"robot": "h1", "num_envs": 256, "categories": ["gap"], "category_weights": None, "levels": [0, 1],
           "variants": None, "num_threads": 1, "physics": "mujoco", "resident": None, "seed": 0, "domain_rand": False,
           "curriculum": True, "episode_length_s": 20.0, "cmd_speed": 0.5, "gait_period": 0.8, "gait_stance": 0.55,
           "gait_amplitude": 0.25, "gait_feedforward": 0.0, "feet_edge_from_level": 4, "pit_depths": None,
           "reward_overrides": {"alive": 2.0}, "depth": None, "depth_source": "host", "action_delay_after_steps": 0}


def test_recorded_configs_of_the_old_layout_are_upgraded():
    old = {"env": OLD_ENV, "ppo": {"learning_rate": 3e-4, "weight": 1.0}, "hlm": {"enabled": True}}
    new = upgrade_recorded_config(old)
    assert old["env"]["domain_rand"] is False  # not modified
    env = new["env"]
    assert env["domain_rand"] == {**env_defaults()["domain_rand"], "enabled": False, "delay_after_global_steps": 0}
    assert env["curriculum"]["enabled"] is True and env["depth_camera"]["source"] == "host"
    assert env["variants"] == 2 and env["timestep"] == 0.005 and "depth_source" not in env
    assert new["ppo"] == {**ppo_defaults(), "learning_rate": 3e-4, "weight": 1.0} and new["hlm"] == {"enabled": True}
    assert upgrade_recorded_config(new) == new  # today's layout stays
    built = env_config(env, "oracle")  # the same env the old layout's builder made
    assert not built.domain_rand.friction and built.depth_camera.source == "host" and built.variants == 2


def test_committed_run_configs_upgrade_to_configs_today_builds():
    for path in ("checkpoints/student_h1.pt", "checkpoints/oracle_h1.pt", "checkpoints/oracle_h1_clocked.pt"):
        state = load_checkpoint(ROOT / path)
        config = upgrade_recorded_config(state["config"])
        env = env_config(config["env"], state["meta"]["kind"], **policy_env_kwargs(state["meta"]))  # (a student's: its teacher's)
        assert env.robot == "h1"
        ppo_config(config["ppo"], ("weight",))


def test_domain_rand_off_and_only_turn_single_terms_on():
    """``off()`` switches every term off with the master switch on, so replacing one term turns
    that term alone on; ``only`` turns the named terms on even in a section whose master switch
    was off; the master switch off forces every term off."""
    from legoh_rl.envs.randomization import DOMAIN_RAND_TERMS

    off = DomainRandConfig.off()
    assert off.enabled and not any(getattr(off, t) for t in DOMAIN_RAND_TERMS)
    pushes = dataclasses.replace(off, push=True)
    assert [t for t in DOMAIN_RAND_TERMS if getattr(pushes, t)] == ["push"]
    master_off = DomainRandConfig(enabled=False)
    assert not any(getattr(master_off, t) for t in DOMAIN_RAND_TERMS)
    only = master_off.only(["push", "action_delay"])
    assert only.enabled and [t for t in DOMAIN_RAND_TERMS if getattr(only, t)] == ["push", "action_delay"]


def test_recipe_keys_are_a_fresh_copy_and_follow_an_edited_yaml(tmp_path):
    """recipe_keys keeps the parsed files per process: each call still gets its own dict, and an
    edited yaml (the recipe's or a group option's) is read again."""
    from legoh_rl.training.config_checks import recipe_keys

    (tmp_path / "group").mkdir()
    (tmp_path / "group" / "a.yaml").write_text("width: 8\n")
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text("defaults:\n  - group: a\n  - _self_\nseed: 1\n")
    first = recipe_keys(recipe)
    assert first == {"group": {"width": 8}, "seed": 1}
    first["group"]["width"] = 99
    assert recipe_keys(recipe)["group"]["width"] == 8
    (tmp_path / "group" / "a.yaml").write_text("width: 8\ndepth: 2\n")
    assert recipe_keys(recipe) == {"group": {"width": 8, "depth": 2}, "seed": 1}
    recipe.write_text("defaults:\n  - group: a\n  - _self_\nseed: 1\nlr: 0.5\n")
    assert recipe_keys(recipe)["lr"] == 0.5
