"""TensorDict transforms for perception (paper Sec. TC-ViT); usable on any TorchRL env.

* :class:`DepthHistory` -- 16 depth frames kept, every 4th returned as ``depth_stack``
  ``(4, H, W)`` (oldest first), frames entering only on perception ticks.
* :class:`GoalTiling` -- the goal vector as extra image plane(s): ``depth_goal_stack``
  ``(4, 1 + G, H, W)``; :meth:`GoalTiling.decode` inverts the encoding.
* :class:`PerceptionHold` -- a TensorDictModule wrapper running the perception module on
  ticking worlds only, holding ``z_uni``/``delta_g0``/``goals_uni`` in between (latent tiling)
  and forwarding ``goal_next`` = g_1 (nearest-goal forwarding); ``hold_forward`` for training.

See ``docs/transforms.md``.
"""

from legoh_rl.transforms.depth_history import DepthHistory
from legoh_rl.transforms.goal_tiling import GoalTiling
from legoh_rl.transforms.perception_hold import PerceptionHold

__all__ = ["DepthHistory", "GoalTiling", "PerceptionHold"]
