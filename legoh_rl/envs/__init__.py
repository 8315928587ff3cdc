"""The humanoid hiking benchmark: robots, batched physics, trails, sensors, rewards, the env.

Importing this package registers the Gymnasium ids ``LegoH/Hike-H1-v0``, ``LegoH/Hike-G1-v0``
(oracle observations) and ``LegoH/HikeDepth-H1-v0``, ``LegoH/HikeDepth-G1-v0`` (with depth), each
with a vector entry point: ``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``
is one batched env of N worlds (:class:`~legoh_rl.envs.gym_env.HikingVectorEnv`).
"""

import gymnasium as _gym

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv

__all__ = ["HikingEnv", "HikingEnvConfig"]

for _robot in ("H1", "G1"):
    for _name, _mode in (("Hike", "oracle"), ("HikeDepth", "student")):
        _id = f"LegoH/{_name}-{_robot}-v0"
        if _id not in _gym.registry:
            _gym.register(
                id=_id,
                entry_point="legoh_rl.envs.gym_env:HikingGymEnv",
                vector_entry_point="legoh_rl.envs.gym_env:HikingVectorEnv",
                kwargs={"robot": _robot.lower(), "mode": _mode},
                max_episode_steps=None,
            )
