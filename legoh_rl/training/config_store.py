"""The recipes' ``env`` and ``ppo`` sections as hydra config groups, read from their dataclasses.

Each default and each allowed value is written once, in the dataclass field
(:func:`legoh_rl.kinds.setting`): :class:`~legoh_rl.envs.config.HikingEnvConfig` (with its
sections ``depth_camera``, ``domain_rand``, ``curriculum``) and
:class:`~legoh_rl.objectives.ppo.PPOConfig`. :func:`register_configs` stores their defaults in
hydra's :class:`~hydra.core.config_store.ConfigStore` as ``env/hiking`` and ``ppo/default``; a
recipe's yaml lists them in its defaults and sets in its own sections only what it chooses
differently. Every field is a setting of every training recipe (``env.decimation=2``,
``env.domain_rand.push=false``, ``ppo.clip_value=false``), checked by the same kinds
(:func:`env_config`, :func:`ppo_config`), but :data:`SET_BY_RECIPE`.

Configs recorded by runs made before the sections had this layout (checkpoints' ``config``) are
read through :func:`upgrade_recorded_config`.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping

from hydra.core.config_store import ConfigStore

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.kinds import build_section, section_defaults
from legoh_rl.objectives.ppo import PPOConfig

__all__ = ["SET_BY_RECIPE", "env_defaults", "ppo_defaults", "env_config", "ppo_config", "refuse_set_by_recipe", "register_configs",
           "upgrade_recorded_config"]

#: :class:`HikingEnvConfig` fields that are not settings of a recipe's ``env`` section, and why
SET_BY_RECIPE = {
    "mode": "the recipe's kind of training (oracle_ppo: oracle; unified: student)",
    "device": "the recipe's device=... (auto | cpu | cuda[:i]): the env's tensors follow it",
}


def env_defaults() -> dict:
    """The ``env`` group's node: every :class:`HikingEnvConfig` field but :data:`SET_BY_RECIPE`,
    with its default (tuples as lists, sections as mappings)."""
    return section_defaults(HikingEnvConfig, skip=SET_BY_RECIPE)


def ppo_defaults() -> dict:
    """The ``ppo`` group's node: every :class:`PPOConfig` field with its default."""
    return section_defaults(PPOConfig)


def _plain(section) -> dict:
    """A config section (DictConfig or mapping) as plain containers, interpolations resolved."""
    from omegaconf import DictConfig, OmegaConf

    if isinstance(section, DictConfig):
        return OmegaConf.to_container(section, resolve=True)
    return copy.deepcopy(dict(section))


def env_config(section: Mapping, mode: str, **fixed) -> HikingEnvConfig:
    """The :class:`HikingEnvConfig` of a recipe's ``env`` section, checked field by field (each
    refusal names ``env.<key>``), in ``mode``; ``fixed``: other fields the recipe sets (its
    ``device``, a teacher's gait clock).

    Raises:
        ValueError: a bad key or value, or a combination the dataclass refuses (``env: ...``).
    """
    values = _plain(section)
    refuse_set_by_recipe(values)
    values.update(fixed)  # (a teacher's gait clock replaces the section's)
    own = {k: values.pop(k) for k in list(values) if k in SET_BY_RECIPE}
    return build_section(HikingEnvConfig, values, "env", mode=mode, **own)


def refuse_set_by_recipe(env: Mapping) -> None:
    """Refuse an ``env`` section that sets a field of :data:`SET_BY_RECIPE` (ValueError naming it)."""
    for key, why in SET_BY_RECIPE.items():
        if key in env:
            raise ValueError(f"env.{key}={env[key]!r} is not a setting: it is {why}")


def ppo_config(section: Mapping, recipe_keys=()) -> PPOConfig:
    """The :class:`PPOConfig` of a recipe's ``ppo`` section, checked field by field (each refusal
    names ``ppo.<key>``); ``recipe_keys``: the section's keys that are the recipe's own (unified's
    ``weight``), left to it."""
    values = {k: v for k, v in _plain(section).items() if k not in recipe_keys}
    return build_section(PPOConfig, values, "ppo")


def register_configs() -> None:
    """Store :func:`env_defaults` as ``env/hiking`` and :func:`ppo_defaults` as ``ppo/default``
    (idempotent; call before hydra composes)."""
    store = ConfigStore.instance()
    store.store(group="env", name="hiking", node=env_defaults())
    store.store(group="ppo", name="default", node=ppo_defaults())


#: keys of the ``env`` section that the recorded configs of older runs hold at other places:
#: old key -> (section, field)
_MOVED = {"depth_source": ("depth_camera", "source"),
          "action_delay_after_steps": ("domain_rand", "delay_after_global_steps")}


def upgrade_recorded_config(config: Mapping | None) -> dict:
    """A config recorded by a training run (a checkpoint's ``config``), in today's layout.

    Runs record their resolved config. Before the ``env`` section held every field of
    :class:`HikingEnvConfig`, it held a subset, in which ``domain_rand`` and ``curriculum`` were
    switches (now ``domain_rand.enabled``, ``curriculum.enabled``), ``depth_source`` was
    ``depth_camera.source`` and ``action_delay_after_steps`` was
    ``domain_rand.delay_after_global_steps``; a null stood for the field's default; the fields it
    left out took their defaults, which the upgraded section now states. The ``ppo`` section
    gains the :class:`PPOConfig` fields it left out, at their defaults (the values such runs had).
    A config in today's layout comes back equal; the argument is not modified.
    """
    out = copy.deepcopy(dict(config or {}))
    env = out.get("env")
    if isinstance(env, Mapping) and "depth_camera" not in env:  # the old layout had no sections
        out["env"] = _upgrade_env(dict(env))
    ppo = out.get("ppo")
    if isinstance(ppo, Mapping):
        out["ppo"] = {**ppo_defaults(), **ppo}
    return out


def _upgrade_env(env: dict) -> dict:
    """An ``env`` section of the old layout (see :func:`upgrade_recorded_config`) in today's."""
    defaults = env_defaults()
    fields = {f.name: f for f in dataclasses.fields(HikingEnvConfig)}
    new = copy.deepcopy(defaults)
    for key, value in env.items():
        if key in ("domain_rand", "curriculum") and not isinstance(value, Mapping):
            new[key]["enabled"] = bool(value)
        elif key in _MOVED:
            section, name = _MOVED[key]
            if value is not None:
                new[section][name] = value
        elif value is None and key in fields and defaults.get(key) is not None:
            pass  # null: the field's default
        else:
            new[key] = value
    return new
