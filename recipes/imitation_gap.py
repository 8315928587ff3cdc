"""How far a student's actions are from its teacher's on the states the student visits, per joint.

    python recipes/imitation_gap.py checkpoints/student_h1.pt outputs/oracle_h1_feedforward/oracle_h1.pt
    python recipes/imitation_gap.py <student> <teacher> --goal-source expert --latent teacher

The student acts deterministically on an evaluation env (as in ``route_following.py``); at every
control step the frozen teacher (an oracle checkpoint) labels the same state from the
privileged observations, as DAgger's labels are made in training. The table gives, per time bin,
the mean absolute action difference ``a_student - a_teacher`` over joints, and the mean signed
difference per joint: a signed mean far from 0 is a bias the student carries on its own states
(a steady difference between left and right legs steers the robot).

Options separate the student's parts:

* ``--goal-source expert``: its locomotion module gets the expert goal instead of its predicted one;
* ``--latent teacher``: its locomotion module gets the teacher's scandot latent ``z_tea`` in
  place of its own ``z_uni`` (the DAgger latent target).

With both, whatever gap remains is the locomotion module's own imitation error.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from legoh_rl.training.distill import Teacher
from legoh_rl.training.policies import load_cell_policy
from legoh_rl.training.probes import probe_parser, with_expert_goal


def imitation_gap(student: str, teacher: str, category: str = "randommix", level: int = 0, robots: int = 8,
                  seconds: float = 12.0, seed: int = 0, variants: int = 8, goal_source: str = "predicted",
                  latent: str = "student") -> dict:
    """Per-step action differences of ``student`` against ``teacher`` on the student's rollout.

    Returns:
        ``{"time": (T,) s, "diff": (T, robots, A) a_student - a_teacher (NaN once a robot's first
        episode has ended), "joints": the A leg joint names}``.

    Raises:
        ValueError: ``student`` is not a student checkpoint, the teacher is for another robot,
            or an unknown ``goal_source`` / ``latent``.
    """
    if latent not in ("student", "teacher"):
        raise ValueError(f"latent must be 'student' or 'teacher', got {latent!r}")
    if goal_source not in ("predicted", "expert"):
        raise ValueError(f"goal_source must be 'predicted' or 'expert', got {goal_source!r}")
    env, policy, kind, base = load_cell_policy(student, category, level, robots, seed, variants)
    if not kind.startswith("student"):
        raise ValueError(f"{student}: imitation_gap needs a student checkpoint, got a {kind} policy")
    tea = Teacher(teacher, base.cfg.robot)
    if goal_source == "expert":
        policy = with_expert_goal(policy, kind)
    hold, actor = policy[:-1], policy[-1]
    if latent == "teacher":
        z_tea = TensorDictModule(lambda td_z: td_z.clone(), in_keys=["z_tea"], out_keys=["z_uni"])
        actor = TensorDictSequential(z_tea, actor)
    env.set_seed(seed)
    base.assign_tiles(np.full(robots, level), np.full(robots, base.trails.categories.index(category)))
    td = env.reset()
    diffs, ended = [], np.zeros(robots, bool)
    steps = min(int(round(seconds / base.dt)), base.max_steps)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in tqdm(range(steps), desc="imitation_gap", unit="steps", leave=False):
            td = hold(td)
            labels = tea.label(td.select(*tea.in_keys).copy())
            td.set("z_tea", labels["z_tea"])
            td = actor(td)
            d = (td["action"] - labels["action_tea"]).numpy()
            diffs.append(np.where(ended[:, None], np.nan, d))
            out, td = env.step_and_maybe_reset(td)
            ended |= out["next", "done"].reshape(-1).numpy()
            if ended.all():
                break
    return {"time": np.arange(len(diffs)) * base.dt, "diff": np.array(diffs), "joints": base.robot.leg_joints}


def gap_table(result: dict, edges_s: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 4.0, 6.0, 9.0, 12.0)) -> str:
    """Markdown: per time bin, mean |a_s - a_t| over joints and robot-steps, and the signed mean per joint."""
    joints = [j.replace("_joint", "") for j in result["joints"]]
    lines = ["| time (s) | mean abs | " + " | ".join(joints) + " |", "|---|---:|" + "---:|" * len(joints)]
    t, d = result["time"], result["diff"]
    for lo, hi in zip(edges_s[:-1], edges_s[1:], strict=True):
        w = d[(t >= lo) & (t < hi)]
        if w.size == 0 or np.isnan(w).all():
            continue
        signed = np.nanmean(w, axis=(0, 1))
        lines.append(f"| {lo:g}-{hi:g} | {np.nanmean(np.abs(w)):.3f} | " + " | ".join(f"{x:+.2f}" for x in signed) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = probe_parser(__doc__, seconds=12.0)
    parser.add_argument("teacher", help="the oracle checkpoint that labels the student's states")
    parser.add_argument("--variants", type=int, default=8)
    parser.add_argument("--goal-source", default="predicted", choices=("predicted", "expert"))
    parser.add_argument("--latent", default="student", choices=("student", "teacher"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    result = imitation_gap(args.checkpoint, args.teacher, args.category, args.level, args.robots, args.seconds,
                           args.seed, args.variants, args.goal_source, args.latent)
    print(f"{args.checkpoint} against {args.teacher} on {args.category} level {args.level} (seed {args.seed}, "
          f"{args.robots} robots, {args.goal_source} goal, {args.latent} latent); action units (q* = q0 + 0.25 a)")
    print(gap_table(result))


if __name__ == "__main__":
    main()
