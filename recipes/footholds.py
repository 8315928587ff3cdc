"""Where a policy's feet miss: the first foothold over a pit of each robot on one trail level.

    python recipes/footholds.py checkpoints/oracle_h1.pt --category gap --level 1 --robots 24 --seed 7401
    python recipes/footholds.py checkpoints/oracle_h1.pt --category ditch --level 2 --variants 4

The policy acts deterministically on an evaluation env built from the checkpoint (as in
``recipes/evaluate.py``). For each robot the probe records the first control step at which a foot
in contact with the ground stands over a pit sample of the terrain (the same test as the
``feet_in_pit`` reward term), and how far that foot is from solid ground ahead of it (+x, the
trail's direction), behind it and to either side, walking the heightfield sample by sample. The
miss is *short* (the nearest solid ground is ahead: the foot came down before the next stone or
platform), *long* (behind: the foot is just past the last edge) or *lateral* (solid ground is
nearer to the side: beside a stone). The table gives the counts and, per robot, the time from
that foothold to the end of its episode (a fall, usually). A policy that steps over pits but
misses by one heightfield sample (0.1 m) is limited by foot placement, not by the skill.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from legoh_rl.training.policies import load_cell_policy
from legoh_rl.training.probes import probe_parser

#: how far (m) the probe looks for solid ground from a foot over a pit
REACH = 1.5


def distance_to_solid(pit: np.ndarray, index: tuple[int, int], step: tuple[int, int], resolution: float,
                      reach: float = REACH) -> float:
    """Distance (m) from sample ``index`` of the (nx, ny) bool ``pit`` mask to the first non-pit
    sample along ``step`` (one of (+-1, 0), (0, +-1)); ``inf`` within ``reach`` or the map's edge."""
    i, j = index
    for k in range(1, int(round(reach / resolution)) + 1):
        ii, jj = i + step[0] * k, j + step[1] * k
        if not (0 <= ii < pit.shape[0] and 0 <= jj < pit.shape[1]):
            break
        if not pit[ii, jj]:
            return k * resolution
    return math.inf


def miss_kind(pit: np.ndarray, origin: tuple[float, float], resolution: float, xy) -> dict:
    """Classify a foothold at world ``xy`` (2,) over a pit sample of ``pit`` (nx, ny) bool, whose
    sample (0, 0) lies at world ``origin`` with spacing ``resolution`` (m).

    Returns:
        ``{"kind": "short" | "long" | "lateral", "ahead", "behind", "side"}``: the distances (m)
        to solid ground in +x, in -x and the nearer of +-y (``inf``: none within :data:`REACH`).
    """
    index = (int(round((xy[0] - origin[0]) / resolution)), int(round((xy[1] - origin[1]) / resolution)))
    ahead = distance_to_solid(pit, index, (1, 0), resolution)
    behind = distance_to_solid(pit, index, (-1, 0), resolution)
    side = min(distance_to_solid(pit, index, (0, 1), resolution), distance_to_solid(pit, index, (0, -1), resolution))
    kind = "lateral" if side < min(ahead, behind) else ("short" if ahead <= behind else "long")
    return {"kind": kind, "ahead": ahead, "behind": behind, "side": side}


def footholds(checkpoint: str, category: str = "gap", level: int = 1, robots: int = 8, seconds: float = 10.0,
              seed: int = 0, variants: int = 8) -> dict:
    """Roll ``checkpoint``'s policy on one (category, level) cell of ``variants`` trail variants
    (robots spread over them; with deterministic actions and no randomisation, robots on the same
    variant walk alike) and classify each robot's first foothold over a pit.

    Returns:
        ``{"robots", "on_pit" (robots with such a foothold), "short", "long", "lateral" (counts),
        "events": [{"robot", "time_s", "kind", "ahead", "behind", "side", "end_s"}]}``, ``end_s`` the
        episode's end (``nan``: still going at ``seconds``).

    Raises:
        ValueError: non-positive ``robots`` or ``seconds``; trails without a pit mask.
    """
    if robots < 1 or seconds <= 0:
        raise ValueError(f"need robots >= 1 and seconds > 0, got {robots}, {seconds}")
    env, policy, _, base = load_cell_policy(checkpoint, category, level, robots, seed, variants)
    grid = getattr(base.trails, "grid", None)
    if grid is None:
        raise ValueError(f"footholds needs trails with a pit mask (a trail grid); got {type(base.trails).__name__}")
    tm = grid.map
    events: dict[int, dict] = {}
    end = np.full(robots, np.nan)
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for k in tqdm(range(int(round(seconds / base.dt))), desc="footholds", unit="steps", leave=False):
            td = env.step(policy(td))["next"]
            state = base.read_state()
            on_pit = tm.pit_at(state["feet_xy"].reshape(-1, 2)).reshape(-1, 2) & state["contact"]
            for n, f in zip(*np.nonzero(on_pit), strict=True):
                if n not in events and np.isnan(end[n]):
                    events[n] = {"robot": int(n), "time_s": (k + 1) * base.dt,
                                 **miss_kind(tm.pit, tm.origin, tm.resolution, state["feet_xy"][n, f])}
            done = td["done"].numpy().reshape(-1)
            end[np.isnan(end) & done] = (k + 1) * base.dt
            if not np.isnan(end).any():
                break
    rows = [{**events[n], "end_s": float(end[n])} for n in sorted(events)]
    kinds = [r["kind"] for r in rows]
    return {"robots": robots, "on_pit": len(rows), **{k: kinds.count(k) for k in ("short", "long", "lateral")},
            "events": rows}


def main() -> None:
    parser = probe_parser(__doc__, seconds=10.0)
    parser.set_defaults(category="gap", level=1)
    parser.add_argument("--variants", type=int, default=8, help="trail variants the robots are spread over")
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = footholds(args.checkpoint, args.category, args.level, args.robots, args.seconds, args.seed, args.variants)
    print(f"{args.checkpoint} on {args.category} level {args.level}: {out['on_pit']} of {out['robots']} robots put a "
          f"foot on a pit within {args.seconds:g} s (short {out['short']}, long {out['long']}, "
          f"lateral {out['lateral']})\n")
    print("| robot | at (s) | miss | solid ahead (m) | behind (m) | side (m) | episode end (s) |")
    print("|---:|---:|---|---:|---:|---:|---:|")
    for r in out["events"]:
        print(f"| {r['robot']} | {r['time_s']:.2f} | {r['kind']} | {r['ahead']:.1f} | {r['behind']:.1f} | "
              f"{r['side']:.1f} | {r['end_s']:.2f} |")


if __name__ == "__main__":
    main()
