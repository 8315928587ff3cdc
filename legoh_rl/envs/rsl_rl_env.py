"""The hiking env as an rsl_rl ``VecEnv`` (rsl-rl-lib 5.5): train it with rsl_rl's ``OnPolicyRunner``.

Install the extra: ``pip install 'legoh-rl[rsl_rl]'``. Then::

    from rsl_rl.runners import OnPolicyRunner
    from legoh_rl.envs import HikingEnvConfig
    from legoh_rl.envs.rsl_rl_env import OBS_GROUPS, HikingRslRlEnv

    env = HikingRslRlEnv(HikingEnvConfig(robot="h1", num_envs=256))
    train_cfg = {"num_steps_per_env": 24, "save_interval": 50, "obs_groups": dict(OBS_GROUPS),
                 "algorithm": {"class_name": "PPO"},
                 "actor": {"class_name": "MLPModel", "hidden_dims": [512, 256, 128],
                           "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 1.0}},
                 "critic": {"class_name": "MLPModel", "hidden_dims": [512, 256, 128]}}
    runner = OnPolicyRunner(env, train_cfg, log_dir="runs/rsl_rl", device="cpu")
    runner.learn(1500)
    runner.export_policy_to_onnx("runs/rsl_rl")      # input "obs" = the "policy" group

Observation groups (a TensorDict of batch [N] on the env's device, see :class:`HikingRslRlEnv`):
``"policy"`` holds what a deployable policy may read, ``"critic"`` adds the privileged state
for an asymmetric critic; rsl_rl's ``obs_groups`` maps its observation sets to them
(:data:`OBS_GROUPS`: the actor reads ``"policy"``, the critic ``"critic"``). With the depth
camera on (student and eval modes), a ``"depth"`` group (N, 1, H, W) is there too, for rsl_rl's
``CNNModel`` (``"actor": ["policy", "depth"]``).
"""

from __future__ import annotations

try:
    from rsl_rl.env import VecEnv
except ImportError as err:  # the optional extra
    raise ImportError(
        "legoh_rl.envs.rsl_rl_env needs rsl_rl (the rsl-rl-lib package, 5.5): "
        "pip install 'legoh-rl[rsl_rl]'"
    ) from err

import torch
from tensordict import TensorDict, TensorDictBase

from legoh_rl.envs.autoreset import step_autoreset
from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv
from legoh_rl.envs.metrics import METRIC_NAMES

__all__ = ["OBS_GROUPS", "POLICY_KEYS", "PRIVILEGED_KEYS", "HikingRslRlEnv"]

#: rsl_rl's ``obs_groups`` for an MLP actor on the ``"policy"`` group and an asymmetric critic on
#: the ``"critic"`` group (copy it into the runner's config: rsl_rl writes into that dict).
OBS_GROUPS: dict[str, list[str]] = {"actor": ["policy"], "critic": ["critic"]}

#: The ``"policy"`` group's default env keys per mode: the oracle's own inputs without its
#: privileged state (proprioception, scandots, expert goal directions); for a student (depth
#: modes) proprioception and the two GPS vectors, as the paper's student reads beside its depth.
POLICY_KEYS: dict[str, tuple[str, ...]] = {
    "oracle": ("proprio", "scandots", "expert_goals"),
    "student": ("proprio", "goal_gps", "waypoint_gps"),
    "eval": ("proprio", "goal_gps", "waypoint_gps"),
}
#: What the ``"critic"`` group adds to the policy keys by default: the privileged observation
#: (base linear velocity, friction, mass and CoM offsets, motor strengths: docs/observations.md)
#: and whatever privileged terrain knowledge the policy does not read.
PRIVILEGED_KEYS: dict[str, tuple[str, ...]] = {
    "oracle": ("privileged",),
    "student": ("scandots", "expert_goals", "privileged"),
    "eval": ("scandots", "expert_goals", "privileged"),
}
_FLAT_KEYS = ("proprio", "goal_gps", "waypoint_gps", "scandots", "privileged", "expert_goals")


class HikingRslRlEnv(VecEnv):
    """A :class:`~legoh_rl.envs.hiking.HikingEnv` of N worlds behind rsl_rl's ``VecEnv`` interface.

    Args:
        env: a built :class:`HikingEnv`, or the :class:`HikingEnvConfig` to build one (default:
            ``HikingEnvConfig()``).
        trails: the terrain, when ``env`` is a config (see :class:`HikingEnv`).
        policy_keys: env observation keys of the ``"policy"`` group, flattened and concatenated
            in this order (default :data:`POLICY_KEYS` of the env's mode).
        critic_keys: keys of the ``"critic"`` group (default: the policy keys followed by
            :data:`PRIVILEGED_KEYS` of the mode).

    Observations (:meth:`get_observations`, :meth:`step`): a TensorDict of batch [N] with
    ``"policy"`` (N, D_policy) and ``"critic"`` (N, D_critic) float32 (H1 oracle: D_policy = 37 +
    132 + 6 = 175, D_critic = 175 + 18 = 193), and ``"depth"`` (N, 1, H, W) when the env casts
    depth.

    Step: ``step(actions (N, A))`` returns ``(obs, rewards (N,) float32, dones (N,) long,
    extras)``. A world whose episode ended is reset within the step (the returned observation
    is its new episode's first), as rsl_rl expects. ``extras["time_outs"]`` (N,) bool marks the
    ends that are truncations (episode length or a diverged physics step), which rsl_rl's PPO
    bootstraps; ``extras["log"]`` (only on steps where episodes end) holds the ended episodes'
    metrics, ``"Episode/<metric>"`` -> (k,) tensors (success, trail_completion, traverse_rate,
    mev, ttf, time_to_reach of the episodes that reached P_B, level; docs/metrics.md), which
    rsl_rl's logger averages per iteration.

    Attributes: ``num_envs`` N, ``num_actions`` A, ``max_episode_length`` (control steps),
    ``episode_length_buf`` (N,) int64 (the env's own episode clock; assigning it, as
    ``learn(init_at_random_ep_len=True)`` does, moves each world's clock), ``device``, ``cfg``
    (the :class:`HikingEnvConfig`), ``step_dt`` (control period, s), ``env`` (the HikingEnv).

    Raises:
        ValueError: an unknown observation key, a key that is not a flat vector in a group, or
            ``trails`` given with a built env.
    """

    def __init__(self, env: HikingEnv | HikingEnvConfig | None = None, trails=None,
                 policy_keys: tuple[str, ...] | None = None, critic_keys: tuple[str, ...] | None = None) -> None:
        if env is None or isinstance(env, HikingEnvConfig):
            env = HikingEnv(env or HikingEnvConfig(), trails=trails)
        elif not isinstance(env, HikingEnv):
            raise TypeError(f"env must be a HikingEnv or a HikingEnvConfig, got {type(env).__name__}")
        elif trails is not None:
            raise ValueError("trails builds a new env from a config; the given HikingEnv already has its trails")
        self.env = env
        self.cfg = env.cfg
        self.num_envs = int(env.batch_size[0])
        self.num_actions = int(env.A)
        self.max_episode_length = int(env.max_steps)
        self.device = env.device
        self.step_dt = float(env.dt)
        mode = env.cfg.mode
        self.policy_keys = tuple(POLICY_KEYS[mode] if policy_keys is None else policy_keys)
        self.critic_keys = tuple(self.policy_keys + PRIVILEGED_KEYS[mode] if critic_keys is None else critic_keys)
        available = set(env.observation_spec.keys())
        for group, keys in (("policy", self.policy_keys), ("critic", self.critic_keys)):
            if not keys:
                raise ValueError(f"the {group!r} group needs at least one observation key, got none")
            for key in keys:
                if key not in _FLAT_KEYS or key not in available:
                    raise ValueError(f"{group} key {key!r} is not a flat observation of this env; valid: "
                                     f"{[k for k in _FLAT_KEYS if k in available]} (depth is its own group)")
        self._depth = "depth" in available
        self._obs = self._groups(env.reset())

    # ------------------------------------------------------------------ rsl_rl's VecEnv
    def get_observations(self) -> TensorDict:
        """The current observation groups (those of the last reset or step)."""
        return self._obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Apply (N, A) actions to all worlds and reset the worlds whose episode ended.

        Returns:
            ``(obs, rewards (N,), dones (N,) long, extras)`` (see the class docstring).

        Raises:
            ValueError: ``actions`` is not (N, A).
        """
        step, obs, done = step_autoreset(self.env, actions.detach())
        self._obs = self._groups(obs)
        n = self.num_envs
        rewards = step.get("reward").reshape(n)
        extras: dict = {"time_outs": step.get("truncated").reshape(n)}
        if bool(done.any()):
            episode = step.get("episode")
            log = {}
            for name in (*METRIC_NAMES, "level"):
                values = episode.get(name).reshape(n)[done].float()
                values = values[~torch.isnan(values)]  # time_to_reach: only episodes that reached P_B
                if values.numel():
                    log[f"Episode/{name}"] = values
            extras["log"] = log
        return self._obs, rewards, done.long(), extras

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """(N,) int64: control steps since each world's last reset (the env's clock, shared; on
        the simulation's device with a device-resident step)."""
        return torch.as_tensor(self.env.step_state.episode_step)

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        value = torch.as_tensor(value)
        if tuple(value.shape) != (self.num_envs,):
            raise ValueError(f"episode_length_buf must have shape ({self.num_envs},), got {tuple(value.shape)}")
        self.env.step_state.set_episode_step(value.detach().to("cpu", torch.int64).numpy())

    @property
    def unwrapped(self) -> HikingRslRlEnv:
        """This adapter (rsl_rl's extensions read ``env.unwrapped.step_dt``)."""
        return self

    def close(self) -> None:
        """Close the env (frees its renderer, if any)."""
        self.env.close(raise_if_closed=False)

    # ------------------------------------------------------------------ groups
    def _groups(self, td: TensorDictBase) -> TensorDict:
        n = self.num_envs

        def flat(keys: tuple[str, ...]) -> torch.Tensor:
            return torch.cat([td.get(k).reshape(n, -1) for k in keys], dim=-1)

        groups = {"policy": flat(self.policy_keys), "critic": flat(self.critic_keys)}
        if self._depth:
            groups["depth"] = td.get("depth")
        return TensorDict(groups, batch_size=[n], device=self.device)
