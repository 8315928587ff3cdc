"""The recipes' ``env`` defaults as a hydra config, read from :class:`HikingEnvConfig`.

Each env default is written once, in the dataclass. :func:`register_configs` stores them in
hydra's :class:`~hydra.core.config_store.ConfigStore` as the option ``hiking`` of the config group
``env``; a recipe's yaml starts its defaults list with ``- env: hiking`` and sets in its own
``env:`` section only what the recipe chooses differently (batch size, reward additions). Every
key stays overridable from the command line (``env.levels=[0,1]``).
"""

from __future__ import annotations

import dataclasses

from hydra.core.config_store import ConfigStore

from legoh_rl.envs import HikingEnvConfig
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.envs.sensors import DepthCameraConfig

__all__ = ["RECIPE_ENV_KEYS", "env_defaults", "register_configs"]

#: The :class:`HikingEnvConfig` fields a recipe's ``env`` section sets (see
#: :func:`legoh_rl.training.builders.env_config`); ``domain_rand`` and ``curriculum`` are switches
#: there (``false``: off), not the nested configs; ``depth_source`` is ``depth_camera.source``;
#: ``action_delay_after_steps`` is ``domain_rand.delay_after_global_steps`` (env steps per world
#: before the one-step action delay starts; the paper's 24 x 8000).
RECIPE_ENV_KEYS = ("robot", "num_envs", "categories", "category_weights", "levels", "variants", "num_threads", "physics", "resident", "seed",
                   "domain_rand", "curriculum", "episode_length_s", "cmd_speed", "gait_period", "gait_stance",
                   "gait_amplitude", "gait_feedforward", "feet_edge_from_level", "pit_depths", "reward_overrides",
                   "depth", "depth_source", "action_delay_after_steps")
_SWITCHES = ("domain_rand", "curriculum")


def env_defaults() -> dict:
    """``{key: default}`` for :data:`RECIPE_ENV_KEYS`, from the dataclass (tuples as lists,
    switches ``True``)."""
    out: dict = {}
    fields = {f.name: f for f in dataclasses.fields(HikingEnvConfig)}
    for key in RECIPE_ENV_KEYS:
        if key in _SWITCHES:
            out[key] = True
            continue
        if key == "depth_source":
            out[key] = DepthCameraConfig().source
            continue
        if key == "action_delay_after_steps":
            out[key] = DomainRandConfig().delay_after_global_steps
            continue
        f = fields[key]
        value = f.default_factory() if f.default is dataclasses.MISSING else f.default
        out[key] = list(value) if isinstance(value, tuple) else value
    return out


def register_configs() -> None:
    """Store :func:`env_defaults` as ``env/hiking`` (idempotent; call before hydra composes)."""
    ConfigStore.instance().store(group="env", name="hiking", node=env_defaults())
