"""The evaluation with its finished worlds held (``run_protocol(hold_finished=True)``) against
stepping them on to the run's end, alternated in one process.

    python benchmarks/eval_hold.py                                          # student_h1 and oracle_h1
    python benchmarks/eval_hold.py --checkpoints checkpoints/student_g1.pt --robots-per-cell 8 --repeats 3

For each checkpoint the whole benchmark's cells (the five categories x five levels) are evaluated on
one trail grid, ``--repeats`` times each way in the order A B A B ... (A: held, B: stepped on),
timing only :func:`~legoh_rl.training.evaluation.run_protocol` (the env and the policy are built
before the clock starts). Prints a markdown row per checkpoint: the median seconds each way, the
median of the per-pair ratios (stepped-on / held: how many times faster the hold makes the
evaluation), the env steps a run took, the mean episode length as a share of it (the work left
to do once a world has finished is what the hold saves), and whether both ways recorded the same
success per episode.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def one_run(checkpoint: str, protocol, seed: int, variants: int, hold: bool) -> tuple[float, list[dict], int, float]:
    """(seconds, episodes, env steps, dt) of one :func:`run_protocol` on a fresh env and policy."""
    from legoh_rl.training.evaluation import release_memory, run_protocol
    from legoh_rl.training.policies import load_policy

    env, policy, _ = load_policy(checkpoint, protocol, variants=variants, seed=seed, num_threads=1)
    base = getattr(env, "base_env", env)
    started = time.perf_counter()
    result = run_protocol(env, policy, protocol, hold_finished=hold)
    seconds = time.perf_counter() - started
    steps, dt = base.global_steps, base.dt
    env.close()
    del env, policy
    release_memory()
    return seconds, result.episodes, steps, dt


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoints", nargs="+", default=["checkpoints/student_h1.pt", "checkpoints/oracle_h1.pt"])
    p.add_argument("--robots-per-cell", type=int, default=2)
    p.add_argument("--variants", type=int, default=2)
    p.add_argument("--seed", type=int, default=13901, help="the trail grid's seed")
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args(argv)
    if args.repeats < 1 or args.robots_per_cell < 1 or args.variants < 1:
        p.error(f"--repeats, --robots-per-cell and --variants must be >= 1, got {args.repeats}, "
                f"{args.robots_per_cell}, {args.variants}")
    os.environ.setdefault("MUJOCO_GL", "egl")
    import torch

    from legoh_rl.envs.trails import CATEGORIES, NUM_LEVELS
    from legoh_rl.training.evaluation import EvalProtocol

    torch.set_num_threads(1)  # as recipes/evaluate.py
    protocol = EvalProtocol(categories=tuple(CATEGORIES), levels=tuple(range(NUM_LEVELS)),
                            robots_per_cell=args.robots_per_cell, seed=args.seed)
    print(f"{protocol.num_worlds} worlds, grid {args.seed}, {args.variants} variants, {args.repeats} pair(s) "
          "(held, stepped on) per checkpoint\n")
    print("| checkpoint | held (s) | stepped on (s) | speed-up | env steps | mean episode / run | same successes |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for checkpoint in args.checkpoints:
        if not Path(checkpoint).is_file():
            p.error(f"no checkpoint at {checkpoint}")
        held, free, ratios, same = [], [], [], True
        for _ in range(args.repeats):
            a_s, a_ep, steps, dt = one_run(checkpoint, protocol, args.seed, args.variants, hold=True)
            b_s, b_ep, _, _ = one_run(checkpoint, protocol, args.seed, args.variants, hold=False)
            held.append(a_s)
            free.append(b_s)
            ratios.append(b_s / a_s)
            same &= [e["success"] for e in a_ep] == [e["success"] for e in b_ep]
        share = statistics.mean(e["ttf"] for e in a_ep) / (steps * dt)
        print(f"| `{checkpoint}` | {statistics.median(held):.1f} | {statistics.median(free):.1f} | "
              f"**{statistics.median(ratios):.2f}x** | {steps} | {share:.2f} | {'yes' if same else 'no'} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
