"""What the probe recipes (``gait_stats.py``, ``route_following.py``, ``imitation_gap.py``,
``footholds.py``) share: their command line, a checkpoint rolled out on one (category, level)
cell of evaluation trails (:func:`probe_parser`; the policy itself comes from
:func:`~legoh_rl.training.policies.load_cell_policy`), and a student driven by the expert goal
instead of its own prediction (:func:`with_expert_goal`)."""

from __future__ import annotations

import argparse

from tensordict.nn import TensorDictModule, TensorDictSequential

__all__ = ["probe_parser", "with_expert_goal"]


def probe_parser(description: str, seconds: float) -> argparse.ArgumentParser:
    """A parser with ``checkpoint``, ``--category``, ``--level``, ``--robots``, ``--seconds``
    (default ``seconds``) and ``--seed``; recipes add their own options to it."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", help="a policy checkpoint, or 'zero' (hold the default pose)")
    parser.add_argument("--category", default="randommix")
    parser.add_argument("--level", type=int, default=0)
    parser.add_argument("--robots", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=seconds)
    parser.add_argument("--seed", type=int, default=0)
    return parser


def with_expert_goal(policy: TensorDictSequential, kind: str) -> TensorDictSequential:
    """A student's ``(hold, locomotion)`` policy with ``goal_next`` overwritten by row 0 of
    ``expert_goals`` (N, 2) between the two.

    Raises:
        ValueError: ``kind`` is not a student's (an oracle reads the expert goals already).
    """
    if not kind.startswith("student"):
        raise ValueError(f"goal_source='expert' needs a student checkpoint, got a {kind} policy")
    expert = TensorDictModule(lambda goals: goals[..., 0, :].clone(), in_keys=["expert_goals"], out_keys=["goal_next"])
    hold, actor = policy[0], policy[1]
    return TensorDictSequential(hold, expert, actor)
