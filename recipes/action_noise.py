"""How much a policy's exploration noise costs it: success on one trail level with sampled actions.

    python recipes/action_noise.py checkpoints/oracle_h1.pt --category gap --level 3 --stds 0 0.2 0.3 0.5
    python recipes/action_noise.py checkpoints/oracle_h1.pt --category ditch --level 3 --stds 0 0.5 --seed 1

PPO trains on sampled actions, ``loc + std * noise``, and the terrain curriculum promotes a world
on the episodes those actions walk, while ``recipes/evaluate.py`` scores the mean action ``loc``.
This probe rolls the policy on one (category, level) cell with every action std of its Gaussian
head set to each value of ``--stds`` in turn (0: the mean action, as in evaluation) and reports,
per std, how many robots ended their episode within ``--seconds`` and how many of those reached
the trail's end, beside the spread of ``action - loc`` it measured (the std it really acted with).
A cell that the mean action crosses and the sampled one does not is a cell the curriculum keeps a
policy from training on.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from legoh_rl.modules.distributions import GaussianHead, set_action_std
from legoh_rl.training.policies import load_cell_policy
from legoh_rl.training.probes import probe_parser


def noise_success(checkpoint: str, category: str = "gap", level: int = 2, robots: int = 32, seconds: float = 25.0,
                  seed: int = 0, variants: int = 8, stds: tuple[float, ...] = (0.0, 0.3, 0.5)) -> list[dict]:
    """Roll ``checkpoint`` on ``robots`` worlds of one (category, level) cell over ``variants``
    trails, once per action std in ``stds`` (the same trails and starts each time; the action
    noise drawn from ``torch.manual_seed(seed)``).

    Returns:
        one ``{"std", "ended", "success", "robots", "realised_std"}`` per std: robots whose first
        episode ended within ``seconds``, how many of those reached the trail's end, and the
        standard deviation of ``action - loc`` over every step and action (0 for std 0).

    Raises:
        ValueError: a negative std, non-positive ``robots`` or ``seconds``, or a policy without a
            Gaussian head (the zero-action baseline has no noise to set).
    """
    if robots < 1 or seconds <= 0:
        raise ValueError(f"need robots >= 1 and seconds > 0, got {robots}, {seconds}")
    if any(s < 0 for s in stds):
        raise ValueError(f"action stds must be >= 0, got {list(stds)}")
    out = []
    for std in stds:
        env, policy, _, base = load_cell_policy(checkpoint, category, level, robots, seed, variants)
        heads = [m for m in policy.modules() if isinstance(m, GaussianHead)]
        if not heads:
            raise ValueError(f"{checkpoint}: its policy has no Gaussian head whose action std could be set")
        for head in heads:  # the probe sets the std past any ceiling the run trained under
            head.max_std = None
        set_action_std(policy, max(std, max(h.min_std for h in heads)))
        torch.manual_seed(seed)
        ended = np.zeros(robots, dtype=bool)
        success = np.zeros(robots, dtype=bool)
        noise_sq, count = 0.0, 0
        mode = ExplorationType.DETERMINISTIC if std == 0 else ExplorationType.RANDOM
        td = env.reset()
        with torch.no_grad(), set_exploration_type(mode):
            for _ in tqdm(range(int(round(seconds / base.dt))), desc=f"std {std:g}", unit="steps", leave=False):
                td = policy(td)
                noise = td["action"] - td["loc"]
                noise_sq += float((noise**2).sum())
                count += noise.numel()
                nxt = env.step(td)["next"]
                done = nxt["done"].numpy().reshape(-1)
                first = done & ~ended
                success |= first & (nxt["episode", "success"].numpy().reshape(-1) > 0.5)
                ended |= done
                td = nxt
                if ended.all():
                    break
        out.append({"std": float(std), "ended": int(ended.sum()), "success": int(success.sum()), "robots": robots,
                    "realised_std": math.sqrt(noise_sq / max(count, 1))})
    return out


def main() -> None:
    parser = probe_parser(__doc__, seconds=25.0)
    parser.set_defaults(category="gap", level=2, robots=32)
    parser.add_argument("--variants", type=int, default=8, help="trail variants the robots are spread over")
    parser.add_argument("--stds", type=float, nargs="+", default=[0.0, 0.3, 0.5], help="action stds to roll with")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = noise_success(args.checkpoint, args.category, args.level, args.robots, args.seconds, args.seed,
                         args.variants, tuple(args.stds))
    print(f"{args.checkpoint} on {args.category} level {args.level}, {args.robots} robots over {args.variants} "
          f"trails (seed {args.seed}), {args.seconds:g} s\n")
    print("| action std | measured | episodes ended | reached the end |")
    print("|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['std']:g} | {r['realised_std']:.3f} | {r['ended']}/{r['robots']} | {r['success']}/{r['robots']} |")


if __name__ == "__main__":
    main()
