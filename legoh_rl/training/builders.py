"""Small builders shared by the recipes: the env, the oracle, the optimiser, checkpoint metadata, the
shared checks."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import torch
from omegaconf import DictConfig, OmegaConf

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.kinds import check_fields
from legoh_rl.modules.configs import OracleConfig
from legoh_rl.modules.oracle import OracleNetworks, make_oracle_actor_critic, make_oracle_networks
from legoh_rl.objectives.ppo import PPOConfig
from legoh_rl.training.config_checks import (
    Choice,
    Flag,
    Integer,
    Name,
    Number,
    check_known_keys,
    check_settings,
    recipe_keys,
)
from legoh_rl.training.config_store import SET_BY_RECIPE, env_config, refuse_set_by_recipe

__all__ = ["make_env", "eval_env", "oracle_config", "make_oracle", "oracle_networks", "policy_meta",
           "policy_env_kwargs", "require_count", "require_layers", "TRAINING_SETTINGS",
           "check_recipe_settings", "make_adam", "load_optimizer"]

#: the settings both training recipes (``oracle_ppo.py``, ``unified.py``) share, by kind, but the
#: ``env`` and ``ppo`` sections, whose kinds are their dataclasses' fields (``config_store``);
#: (``checkpoint.snapshot_every`` is checked by ``runner.train`` right after ``validate``)
TRAINING_SETTINGS = {
    "experiment_name": Name(nullable=True),
    "stage_name": Name(nullable=True),
    "device": Name(nullable=True),  # which devices: resolve_device
    "collector.steps_per_env": Integer(1),
    "collector.total_frames": Integer(1),
    "collector.workers": Integer(1),
    "collector.allow_new_workers": Flag(),
    "collector.overlap": Flag(),
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
    "fused_adam": Flag(),
}


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
    (``config_file``, ``recipes/config/<recipe>.yaml``, with the groups its defaults list brings
    in) does not have (``env.reward_overrides`` and ``stages`` are free mappings, checked where
    read), ``recipe`` naming this recipe (or null), every field of the ``env`` and ``ppo`` sections
    by its dataclass's kinds (``ppo.<key>`` of ``settings``: the recipe's own keys of that
    section), and every setting of :data:`TRAINING_SETTINGS` and the recipe's ``settings``.

    Raises:
        ValueError: the first bad key; the message names it and its value.
    """
    from pathlib import Path

    recipe = Path(config_file).stem
    check_known_keys(cfg, recipe_keys(config_file), open_sections=("env.reward_overrides", "stages"),
                     name=f"{recipe}'s config")
    check_settings(cfg, {"recipe": Choice((recipe,), nullable=True), **TRAINING_SETTINGS, **settings})
    env = _plain(cfg["env"])
    refuse_set_by_recipe(env)
    check_fields(env, HikingEnvConfig, "env", skip=SET_BY_RECIPE)
    own = tuple(k.split(".", 1)[1] for k in settings if k.startswith("ppo."))
    check_fields({k: v for k, v in _plain(cfg["ppo"]).items() if k not in own}, PPOConfig, "ppo")
    from legoh_rl.training import ray_collection  # (it imports this module)

    ray_collection.collector_backend(cfg["collector"])
    ray_collection.ray_options(cfg["collector"].get("ray"))  # checked whatever the backend: a bad value is one


def _plain(section) -> dict:
    """A config section as plain containers (interpolations resolved)."""
    return OmegaConf.to_container(section, resolve=True) if isinstance(section, DictConfig) else dict(section)


def make_adam(params, lr: float, fused: bool = False) -> torch.optim.Adam:
    """The recipes' Adam over ``params`` at learning rate ``lr``; ``fused`` (the ``fused_adam``
    setting): torch's fused implementation, one kernel per step over every tensor instead of a
    loop of element-wise operations per tensor (a step of TC-ViT's 1.16M parameters 7.4 -> 1.2
    ms, of the oracle's 0.19M 1.8 -> 0.6 ms, BENCHMARKS.md). Its float rounding differs: the
    oracle's parameters after two tiny iterations differ by ~2e-7 (``tests/test_oracle_update.py``)."""
    return torch.optim.Adam(params, lr=lr, **({"fused": True} if fused else {}))


def load_optimizer(optim: torch.optim.Optimizer, state: Mapping) -> None:
    """``optim.load_state_dict(state)`` that keeps the implementation ``optim`` was built with.

    torch's loader takes every entry of the saved parameter groups but their parameters, the
    implementation switches (``fused``, ``foreach``) included: a run resumed with another
    ``fused_adam`` than its checkpoint's would silently go on with the checkpoint's. The moments,
    step counts and learning rates come from ``state``; the switches stay this run's.
    """
    switches = [{k: group[k] for k in ("fused", "foreach") if k in group} for group in optim.param_groups]
    optim.load_state_dict(state)
    for group, kept in zip(optim.param_groups, switches, strict=True):
        group.update(kept)


def make_env(cfg: Mapping, mode: str, trails=None, **overrides) -> HikingEnv:
    """Build the batched env of a recipe's ``env`` section (:func:`~legoh_rl.training.config_store.env_config`;
    ``overrides``: config fields the recipe sets, e.g. ``device``)."""
    return HikingEnv(env_config(cfg, mode, **overrides), trails=trails)


def eval_env(robot: str, protocol, variants: int, seed: int, num_threads=None, depth: bool = False,
             trails=None, device: torch.device | str = "cpu", physics: str = "mujoco", domain_rand: bool | tuple[str, ...] = False,
             **policy_env) -> HikingEnv:
    """The eval-mode env of a protocol (all its categories, ``num_worlds`` worlds), its tensors on
    ``device``, its worlds stepped by ``physics`` (``mujoco`` | ``warp``), with the training's
    randomisation when ``domain_rand`` (``HikingEnvConfig.eval_domain_rand``); ``policy_env``:
    the env fields of the policy's checkpoint (:func:`policy_env_kwargs`: ``gait_period``/
    ``gait_stance``, and ``gait_amplitude``/``gait_feedforward``, of a policy trained with a gait
    clock; ``foot_scan``)."""
    cfg = HikingEnvConfig(robot=robot, num_envs=protocol.num_worlds, mode="eval", depth=depth,
                          categories=tuple(protocol.categories), levels=tuple(protocol.levels),
                          variants=variants, seed=seed, num_threads=num_threads, device=str(device), physics=physics,
                          eval_domain_rand=domain_rand, **policy_env)
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
    the gait clock's period and stance fraction when the env has a clock, its amplitude and
    feedforward gain when the clock drives the PD targets, and ``foot_scan: True`` when the
    scandots end with the feet's scan, ``foot_scan_far: True`` when the far scan follows it (older
    checkpoints, made without them, carry no such fields). :func:`policy_env_kwargs` rebuilds those env settings from the meta block."""
    spec = env.observation_spec
    # a student's depth size (absent for a blind student, trained and evaluated without the camera)
    keys = ("proprio", "privileged", "scandots", "expert_goals") + (("depth",) if kind != "oracle" and "depth" in spec.keys() else ())
    layout = {k: tuple(spec[k].shape[1:]) for k in keys}
    meta = {"robot": env.robot.name, "num_actions": env.A, "obs_layout": layout, "kind": kind}
    if env.cfg.gait_period:
        meta.update(gait_period=env.cfg.gait_period, gait_stance=env.cfg.gait_stance)  # the policy's clock
    if env.cfg.gait_feedforward:  # the clock's swing is part of the policy's actions
        meta.update(gait_amplitude=env.cfg.gait_amplitude, gait_feedforward=env.cfg.gait_feedforward)
    if env.cfg.foot_scan:  # the scandots' layout: 132 base dots, then the feet's scan
        meta["foot_scan"] = True
    if env.cfg.foot_scan_far:  # ... then the feet's far scan
        meta["foot_scan_far"] = True
    return meta


#: the gait clock's env config fields, as :func:`policy_meta` records them
_GAIT_FIELDS = ("gait_period", "gait_stance", "gait_amplitude", "gait_feedforward")


def policy_env_kwargs(meta: Mapping) -> dict:
    """The env config fields that rebuild the env a checkpoint's policy was trained in, from its
    meta block (:func:`policy_meta`): its gait clock's fields where it has a clock, and
    ``foot_scan`` and ``foot_scan_far`` always (False for a checkpoint that records none: its
    scandots are the 132 base dots, or those and the near foot scan). Evaluation, the ONNX loader and a student's env (its teacher's: they replace the
    student config's own) are built with them."""
    out: dict = {k: float(meta[k]) for k in _GAIT_FIELDS if k in meta}
    out["foot_scan"] = bool(meta.get("foot_scan", False))
    out["foot_scan_far"] = bool(meta.get("foot_scan_far", False))
    return out
