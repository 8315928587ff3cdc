"""The gait clock: which foot should be down, and a swing reference for the leg joints.

With ``HikingEnvConfig.gait_period > 0`` each world carries a phase ``phi = t / period mod 1``
(t the episode time). The left leg's phase is ``phi``, the right leg's ``phi + 0.5``; a leg is
in stance while its phase is below the stance fraction. Two reward terms read the clock
(:mod:`legoh_rl.envs.rewards`): ``gait_contact`` (contacts that follow :func:`stance_mask`) and
``gait_joint_ref`` (leg joints that follow :func:`swing_reference`), the periodic contact and
reference-joint terms of Humanoid-Gym and Unitree's RL Gym.
"""

from __future__ import annotations

import numpy as np
from array_api_compat import device

from legoh_rl.envs.array_api import namespace_of

__all__ = ["stance_mask", "swing_joints", "swing_reference"]

# double support around the phase where the swinging leg changes (|sin 2 pi phi| below this)
DEAD_ZONE = 0.1


def stance_mask(phase, stance: float):
    """(N, 2) bool: which feet (left, right) the clock puts on the ground at ``phase`` (N,) in [0, 1)
    (a numpy array or a torch tensor; the result is of the same kind)."""
    xp = namespace_of(phase)
    legs = xp.stack([phase, xp.remainder(phase + 0.5, 1.0)], axis=1)
    return legs < stance


def swing_joints(leg_joints: tuple[str, ...]) -> np.ndarray:
    """(2, 3) indices into ``leg_joints`` of the (hip pitch, knee, ankle pitch) of (left, right).

    Matches H1 (``left_hip_pitch``, ``left_knee``, ``left_ankle``) and G1 (``..._joint``,
    ``left_ankle_pitch_joint``) names.

    Raises:
        ValueError: a leg lacks one of the three joints, or has several (names the leg and joint).
    """
    out = np.zeros((2, 3), dtype=np.int64)
    for i, side in enumerate(("left", "right")):
        for j, part in enumerate(("hip_pitch", "knee", "ankle")):
            hits = [k for k, name in enumerate(leg_joints)
                    if name.startswith(f"{side}_{part}") and (part != "ankle" or "roll" not in name)]
            if len(hits) != 1:
                raise ValueError(f"need exactly one {side} {part} joint among {list(leg_joints)}, found {len(hits)}")
            out[i, j] = hits[0]
    return out


def swing_reference(phase, joints: np.ndarray, num_joints: int, amplitude: float):
    """(N, A) joint offsets from the default pose that the clock asks for at ``phase`` (N,) (a numpy
    array or a torch tensor; the result is of the same kind, dtype and device).

    The swinging leg (left while sin 2 pi phi < 0, right while > 0, i.e. the leg the clock has
    out of stance) folds by ``s = amplitude * |sin 2 pi phi|``: hip pitch -s (thigh forward),
    knee +2s, ankle pitch -s, which lifts the foot while keeping its sole level (H1 and G1 share
    these signs). The stance leg, and both legs while |sin| < 0.1, keep the default pose.
    """
    xp = namespace_of(phase)
    s = xp.sin(2.0 * np.pi * phase)
    s = xp.where(xp.abs(s) < DEAD_ZONE, 0.0, s)
    swing = xp.stack([xp.maximum(-s, 0.0), xp.maximum(s, 0.0)], axis=1) * amplitude  # (N, 2) left, right
    out = xp.zeros((phase.shape[0], num_joints), dtype=phase.dtype, device=device(phase))
    for leg in range(2):
        for j, gain in enumerate((-1.0, 2.0, -1.0)):
            out[:, int(joints[leg, j])] = gain * swing[:, leg]
    return out
