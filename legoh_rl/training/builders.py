"""Small builders shared by the recipes: env configs, the oracle, checkpoint metadata."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import torch

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.config import PHYSICS
from legoh_rl.envs.curriculum import CurriculumConfig
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.envs.rewards import REWARD_FUNCTIONS
from legoh_rl.envs.robots import ROBOTS, get_robot_spec
from legoh_rl.envs.sensors import DEPTH_SOURCES, DepthCameraConfig
from legoh_rl.envs.trail_source import validate_categories
from legoh_rl.envs.trails import ALL_CATEGORIES, NUM_LEVELS
from legoh_rl.modules.configs import OracleConfig
from legoh_rl.modules.oracle import OracleNetworks, make_oracle_actor_critic, make_oracle_networks
from legoh_rl.training.config_checks import (
    Choice,
    Flag,
    Integer,
    ListOf,
    Name,
    Number,
    check_known_keys,
    check_settings,
    recipe_keys,
)
from legoh_rl.training.config_store import RECIPE_ENV_KEYS, env_defaults

__all__ = ["env_config", "make_env", "eval_env", "oracle_config", "make_oracle", "oracle_networks", "policy_meta",
           "gait_kwargs", "require_positive", "require_count", "require_layers", "ENV_SETTINGS", "TRAINING_SETTINGS",
           "check_reward_overrides", "check_recipe_settings"]

#: the recipes' ``env`` section by kind (:mod:`~legoh_rl.training.config_checks`); null keeps the
#: dataclass's default (:func:`env_config`) but for ``robot``, ``num_envs`` and the two switches
ENV_SETTINGS = {
    "env.robot": Choice(tuple(ROBOTS), what="robot"),
    "env.num_envs": Integer(1),
    "env.categories": ListOf(Choice(ALL_CATEGORIES, what="trail category"), single=True, nullable=True),
    "env.category_weights": ListOf(Number(0, low_open=True), nullable=True),
    "env.levels": ListOf(Integer(0, NUM_LEVELS - 1), nullable=True),
    "env.variants": Integer(1, nullable=True),
    "env.num_threads": Integer(1, nullable=True),
    "env.physics": Choice(PHYSICS, nullable=True),
    "env.resident": Flag(nullable=True),
    "env.seed": Integer(0),
    "env.domain_rand": Flag(),
    "env.curriculum": Flag(),
    "env.episode_length_s": Number(0, low_open=True, nullable=True),
    "env.cmd_speed": Number(0, low_open=True, nullable=True),
    "env.gait_period": Number(0, nullable=True),
    "env.gait_stance": Number(0, 1, low_open=True, high_open=True, nullable=True),
    "env.gait_amplitude": Number(0, nullable=True),
    "env.gait_feedforward": Number(0, nullable=True),
    "env.feet_edge_from_level": Integer(0, nullable=True),
    "env.pit_depths": ListOf(Number(0, low_open=True), nullable=True),
    "env.depth": Flag(nullable=True),
    "env.depth_source": Choice(DEPTH_SOURCES, nullable=True),
    "env.action_delay_after_steps": Integer(0, nullable=True),
}
#: the settings both training recipes (``oracle_ppo.py``, ``unified.py``) share, by kind
#: (``checkpoint.snapshot_every`` is checked by ``runner.train`` right after ``validate``)
TRAINING_SETTINGS = {
    "experiment_name": Name(nullable=True),
    "stage_name": Name(nullable=True),
    "device": Name(nullable=True),  # which devices: resolve_device
    "collector.steps_per_env": Integer(1),
    "collector.total_frames": Integer(1),
    "collector.workers": Integer(1),
    "collector.allow_new_workers": Flag(),
    "ppo.clip_epsilon": Number(0, 1, low_open=True),
    "ppo.entropy_coeff": Number(0),
    "ppo.gamma": Number(0, 1),
    "ppo.lmbda": Number(0, 1),
    "ppo.learning_rate": Number(0, low_open=True),
    "ppo.desired_kl": Number(0, low_open=True),
    "ppo.num_epochs": Integer(1),
    "ppo.num_minibatches": Integer(1),
    "ppo.max_grad_norm": Number(0, low_open=True),
    "logger.backend": Choice(("wandb", "csv")),
    "logger.online": Flag(),
    "logger.project": Name(),
    "logger.exp_name": Name(),
    "logger.group": Name(nullable=True),
    "logger.log_every": Integer(1),
    "logger.video_every": Integer(0, nullable=True),
    "logger.video_seconds": Number(0, low_open=True),
    "checkpoint.dir": Name(),
    "checkpoint.every": Integer(1),
    "checkpoint.resume": Name(nullable=True),
    "checkpoint.keep_curriculum": Flag(),
    "checkpoint.overwrite": Flag(),
    "torch_threads": Integer(1),
}


def check_reward_overrides(overrides) -> None:
    """``env.reward_overrides``: null or a mapping of reward term -> weight (a finite number).

    Raises:
        ValueError: not a mapping, an unknown term (lists the known ones) or a weight that is not
            a number; each message names ``env.reward_overrides.<term>``.
    """
    if overrides is None:
        return
    if not isinstance(overrides, Mapping):
        raise ValueError(f"env.reward_overrides must be a mapping of reward term -> weight, got {overrides!r}")
    for term, weight in overrides.items():
        if term not in REWARD_FUNCTIONS:
            raise ValueError(f"env.reward_overrides.{term}: unknown reward term; known terms: {sorted(REWARD_FUNCTIONS)}")
        if not Number().accepts(weight):
            raise ValueError(f"env.reward_overrides.{term} must be a finite number (the term's weight), got {weight!r}")


def require_positive(section: str, cfg: Mapping, *names: str) -> None:
    """Refuse non-positive counts with a message naming ``section.name`` and the value."""
    for name in names:
        value = cfg[name]
        if not isinstance(value, (int, float)) or isinstance(value, bool) or value <= 0:
            where = f"{section}.{name}" if section else name
            raise ValueError(f"{where} must be a positive number, got {value!r}")


def require_count(section: str, cfg: Mapping, *names: str) -> None:
    """Refuse counts that are not positive integers (2.5, 0, "4"), naming ``section.name`` and the value."""
    for name in names:
        value = cfg[name]
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            where = f"{section}.{name}" if section else name
            raise ValueError(f"{where} must be a positive integer, got {value!r}")


def require_layers(name: str, layers) -> None:
    """Refuse MLP widths other than null or a non-empty list of positive integers."""
    if layers is None:
        return
    ok = isinstance(layers, Sequence) and not isinstance(layers, str) and len(layers) > 0 and all(
        isinstance(w, int) and not isinstance(w, bool) and w > 0 for w in layers)
    if not ok:
        raise ValueError(f"{name} must be a non-empty list of positive integers (or null for the defaults), "
                         f"got {list(layers) if isinstance(layers, Sequence) else layers!r}")


def check_recipe_settings(cfg: Mapping, config_file, settings: Mapping) -> None:
    """A training recipe's config checked key by key, before any work: no key its yaml
    (``config_file``, ``recipes/config/<recipe>.yaml``, with the env group) does not have
    (``env.reward_overrides`` and ``stages`` are free mappings, checked where read), ``recipe``
    naming this recipe (or null), every setting of :data:`ENV_SETTINGS`, :data:`TRAINING_SETTINGS`
    and the recipe's own ``settings`` of its kind, and the reward overrides' terms and weights.

    Raises:
        ValueError: the first bad key; the message names it and its value.
    """
    from pathlib import Path

    recipe = Path(config_file).stem
    known = recipe_keys(config_file, {"env": env_defaults()})
    check_known_keys(cfg, known, open_sections=("env.reward_overrides", "stages"), name=f"{recipe}'s config")
    check_settings(cfg, {"recipe": Choice((recipe,), nullable=True), **ENV_SETTINGS, **TRAINING_SETTINGS, **settings})
    check_reward_overrides(cfg["env"].get("reward_overrides"))
    from legoh_rl.training import ray_collection  # (it imports this module)

    ray_collection.collector_backend(cfg["collector"])
    ray_collection.ray_options(cfg["collector"].get("ray"))  # checked whatever the backend: a bad value is one


def env_config(cfg: Mapping, mode: str, **overrides) -> HikingEnvConfig:
    """A :class:`HikingEnvConfig` from a recipe's ``env`` section (validated, nothing built).

    Keys the section leaves out (or sets to null) keep the dataclass's defaults, which are the only
    place env defaults are written. ``domain_rand: false`` and ``curriculum: false`` switch those off;
    ``depth_source`` (``auto | host | warp``) is the depth camera's ``source``;
    ``action_delay_after_steps`` (int >= 0) the env steps per world after which the randomisation's
    one-step action delay starts (``0``: from the first step; no effect with ``domain_rand: false``).
    The env's device is not a key of the section: the recipe's ``device`` sets it (``overrides``).

    Raises:
        ValueError: the section sets ``device`` (the recipe's ``device`` is the one switch: a value here
            would otherwise go unread).
    """
    if cfg.get("device") is not None:
        raise ValueError(f"env.device={cfg.get('device')!r} is not a setting: the recipe's device=... is the one "
                         "switch (auto | cpu | cuda[:i]); the env's tensors follow it")
    unknown = sorted(set(cfg) - set(RECIPE_ENV_KEYS))
    if unknown:
        raise ValueError(f"env.{unknown[0]} is not a setting of the recipes' env section (unknown: {unknown}); "
                         f"the settings are {list(RECIPE_ENV_KEYS)}")
    get_robot_spec(cfg["robot"])  # unknown robot: clear error before any work
    check_reward_overrides(cfg.get("reward_overrides"))
    defaults = {f.name: f.default for f in dataclasses.fields(HikingEnvConfig) if f.default is not dataclasses.MISSING}

    def value(name: str, cast):
        v = cfg.get(name)
        return defaults[name] if v is None else cast(v)

    kwargs = dict(
        robot=cfg["robot"], num_envs=int(cfg["num_envs"]), mode=mode, num_threads=cfg.get("num_threads"),
        categories=validate_categories(cfg.get("categories") or defaults["categories"]),
        levels=value("levels", lambda v: tuple(int(x) for x in v)),
        category_weights=value("category_weights", lambda v: tuple(float(w) for w in v)),
        pit_depths=value("pit_depths", lambda v: tuple(float(d) for d in v)),
        physics=value("physics", str),
        depth=None if cfg.get("depth") is None else bool(cfg["depth"]),  # None: the mode's (on but for the oracle)
        resident=None if cfg.get("resident") is None else bool(cfg["resident"]),  # None: on for warp on cuda
        reward_overrides={str(k): float(v) for k, v in (cfg.get("reward_overrides") or {}).items()},
        **{name: value(name, int) for name in ("variants", "seed", "feet_edge_from_level")},
        **{name: value(name, float) for name in ("episode_length_s", "cmd_speed", "gait_period", "gait_stance",
                                                 "gait_amplitude", "gait_feedforward")},
    )
    delay_after = cfg.get("action_delay_after_steps")
    if delay_after is not None and (isinstance(delay_after, bool) or not isinstance(delay_after, int) or delay_after < 0):
        raise ValueError(f"env.action_delay_after_steps must be an integer >= 0 (env steps per world), got {delay_after!r}")
    if not cfg.get("domain_rand", True):
        kwargs["domain_rand"] = DomainRandConfig.off()
    elif delay_after is not None:
        kwargs["domain_rand"] = DomainRandConfig(delay_after_global_steps=int(delay_after))
    if not cfg.get("curriculum", True):
        kwargs["curriculum"] = CurriculumConfig(enabled=False)
    if cfg.get("depth_source") is not None:
        kwargs["depth_camera"] = DepthCameraConfig(source=str(cfg["depth_source"]))
    kwargs.update(overrides)
    return HikingEnvConfig(**kwargs)


def make_env(cfg: Mapping, mode: str, trails=None, **overrides) -> HikingEnv:
    """Build the batched env of a recipe's ``env`` section (``overrides``: config fields the recipe
    sets, e.g. ``device``)."""
    return HikingEnv(env_config(cfg, mode, **overrides), trails=trails)


def eval_env(robot: str, protocol, variants: int, seed: int, num_threads=None, depth: bool = False,
             trails=None, device: torch.device | str = "cpu", physics: str = "mujoco", domain_rand: bool | tuple[str, ...] = False,
             **gait) -> HikingEnv:
    """The eval-mode env of a protocol (all its categories, ``num_worlds`` worlds), its tensors on
    ``device``, its worlds stepped by ``physics`` (``mujoco`` | ``warp``), with the training's
    randomisation when ``domain_rand`` (``HikingEnvConfig.eval_domain_rand``); ``gait``:
    ``gait_period``/``gait_stance`` (and ``gait_amplitude``/``gait_feedforward``) of a policy
    trained with a gait clock."""
    cfg = HikingEnvConfig(robot=robot, num_envs=protocol.num_worlds, mode="eval", depth=depth,
                          categories=tuple(protocol.categories), levels=tuple(protocol.levels),
                          variants=variants, seed=seed, num_threads=num_threads, device=str(device), physics=physics,
                          eval_domain_rand=domain_rand, **gait)
    return HikingEnv(cfg, trails=trails)


def oracle_networks(state: dict) -> OracleNetworks:
    """The trained networks of an oracle checkpoint (its ``oracle_config`` and ``networks``)."""
    networks = make_oracle_networks(OracleConfig(**state["oracle_config"]))
    networks.load_state_dict(state["networks"])
    return networks


def oracle_config(env: HikingEnv, init_std: float = 1.0, layers: tuple[int, ...] | None = None,
                  max_std: float | None = None) -> OracleConfig:
    """Oracle network sizes read from the env's specs; ``layers`` overrides the actor and critic
    MLP widths (paper: [512, 256, 128]); ``max_std`` caps the action std."""
    spec = env.observation_spec
    extra = {} if layers is None else {"actor_layers": tuple(layers), "critic_layers": tuple(layers)}
    return OracleConfig(
        **extra,
        proprio_dim=spec["proprio"].shape[-1],
        num_actions=env.action_spec.shape[-1],
        privileged_dim=spec["privileged"].shape[-1],
        scandots_dim=spec["scandots"].shape[-1],
        num_goals=spec["expert_goals"].shape[-2],
        init_std=init_std,
        max_std=max_std,
    )


def make_oracle(env: HikingEnv, init_std: float = 1.0, layers: tuple[int, ...] | None = None,
                max_std: float | None = None, network: str = "mlp"):
    """``(networks, actor, critic)`` of the oracle sized for ``env``; ``network``: a name in ``ORACLE_NETWORKS``."""
    ocfg = dataclasses.replace(oracle_config(env, init_std, layers, max_std), network=network)
    networks = make_oracle_networks(ocfg)
    actor, critic = make_oracle_actor_critic(ocfg, networks=networks)
    return networks, actor, critic


def policy_meta(env: HikingEnv, kind: str) -> dict:
    """What a checkpoint must match to be loaded for ``env``: robot, layout, action size, kind, and
    the gait clock's period and stance fraction when the env has a clock, and its amplitude and
    feedforward gain when the clock drives the PD targets (older checkpoints, made without them,
    carry no such fields)."""
    spec = env.observation_spec
    # a student's depth size (absent for a blind student, trained and evaluated without the camera)
    keys = ("proprio", "privileged", "scandots", "expert_goals") + (("depth",) if kind != "oracle" and "depth" in spec.keys() else ())
    layout = {k: tuple(spec[k].shape[1:]) for k in keys}
    meta = {"robot": env.robot.name, "num_actions": env.A, "obs_layout": layout, "kind": kind}
    if env.cfg.gait_period:
        meta.update(gait_period=env.cfg.gait_period, gait_stance=env.cfg.gait_stance)  # the policy's clock
    if env.cfg.gait_feedforward:  # the clock's swing is part of the policy's actions
        meta.update(gait_amplitude=env.cfg.gait_amplitude, gait_feedforward=env.cfg.gait_feedforward)
    return meta


def gait_kwargs(meta: Mapping) -> dict:
    """The env config fields that rebuild a checkpoint's gait clock (empty without one)."""
    keys = ("gait_period", "gait_stance", "gait_amplitude", "gait_feedforward")
    return {k: float(meta[k]) for k in keys if k in meta}
