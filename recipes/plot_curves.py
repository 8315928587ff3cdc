"""Plot learning curves from a recipe's ``metrics.jsonl`` (written beside its checkpoints).

    python recipes/plot_curves.py outputs/oracle_h1 -o docs/img/oracle_h1_curves.png
    python recipes/plot_curves.py outputs/stage1 outputs/stage2 -o curves.png   # resumed stages
    python recipes/plot_curves.py outputs/run_a outputs/run_b --compare --panels student   # overlaid runs

Several run directories are stages of one policy, each resumed from the previous one's
checkpoint: their rows are joined in order (a stage's rows past the next stage's first step are
dropped, since the next stage resumed from an earlier checkpoint) and the stage starts are
marked. ``--smooth k`` overlays a k-iteration running mean on the raw curves; ``--panels gait``
plots the gait signals (goal-velocity tracking, air time, the gait-clock terms) instead of the
main ones, ``--panels student`` the imitation losses and episode metrics of a unified run.
``--compare`` overlays the run directories as separate runs instead, one colour each.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

PANELS = [
    ("reward/total", "reward per step"),
    ("episode/success", "success rate (%)"),
    ("episode/ttf", "time to fall (s)"),
    ("curriculum/mean_level", "mean terrain level"),
    ("episode/traverse_rate", "traverse rate (%)"),
    ("train/action_std", "action std"),
]
GAIT_PANELS = [
    ("reward/tracking_goal_vel", "tracking_goal_vel (weighted, per step)"),
    ("reward/feet_air_time", "feet_air_time (weighted, per step)"),
    ("reward/gait_contact", "gait_contact (weighted, per step)"),
    ("reward/gait_joint_ref", "gait_joint_ref (weighted, per step)"),
    ("episode/ttf", "time to fall (s)"),
    ("episode/trail_completion", "trail completion (%)"),
]
STUDENT_PANELS = [
    ("loss/im_action", "im_action (SmoothL1 to the teacher)"),
    ("loss/im_goals", "im_goals"),
    ("loss/im_latent", "im_latent"),
    ("episode/success", "success rate (%)"),
    ("episode/trail_completion", "trail completion (%)"),
    ("episode/ttf", "time to fall (s)"),
]
PANEL_SETS = {"default": PANELS, "gait": GAIT_PANELS, "student": STUDENT_PANELS}


def load(path: Path) -> list[dict]:
    """The rows of a metrics.jsonl file."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def join_stages(stages: list[list[dict]]) -> tuple[list[dict], list[float]]:
    """Rows of resumed stages as one run, and the step at which each later stage starts."""
    rows: list[dict] = []
    starts: list[float] = []
    for i, stage in enumerate(stages):
        if not stage:
            continue
        if i > 0:
            starts.append(stage[0]["step"])
            rows = [r for r in rows if r["step"] < stage[0]["step"]]
        rows.extend(stage)
    return rows, starts


def running_mean(ys: list[float], k: int) -> list[float]:
    """Mean of the last ``k`` values at each point (fewer at the start)."""
    out, acc = [], 0.0
    for i, y in enumerate(ys):
        acc += y
        if i >= k:
            acc -= ys[i - k]
        out.append(acc / min(i + 1, k))
    return out


def plot(rows: list[dict] | dict[str, list[dict]], out: Path, title: str, stage_starts: list[float] = (),
         smooth: int = 1, panels: list[tuple[str, str]] = PANELS) -> Path:
    """Six panels (``panels``: (metrics key, title) pairs) of training signals against env steps.

    ``rows``: one run's rows, or ``{label: rows}`` for several runs overlaid (one colour each,
    with a legend)."""
    runs = rows if isinstance(rows, dict) else {"": rows}
    fig, axes = plt.subplots(2, 3, figsize=(12, 6))
    for ax, (key, label) in zip(axes.ravel(), panels, strict=True):
        for i, (name, run) in enumerate(runs.items()):
            pts = [(r["step"], r[key]) for r in run if r.get(key) is not None and r[key] == r[key]]
            if not pts:
                continue
            xs, ys = zip(*pts, strict=True)
            ax.plot(xs, ys, lw=1, alpha=0.35 if smooth > 1 else 1.0, color=f"C{i}",
                    label=None if smooth > 1 or not name else name)
            if smooth > 1:
                ax.plot(xs, running_mean(list(ys), smooth), lw=1.5, color=f"C{i}", label=name or None)
        if len(runs) > 1:
            ax.legend(fontsize=8)
        for x in stage_starts:
            ax.axvline(x, color="k", ls="--", lw=0.8, alpha=0.6)
        ax.set_title(label)
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("run_dirs", type=Path, nargs="+",
                        help="a recipe's checkpoint.dir (holds metrics.jsonl), or several resumed stages in order")
    parser.add_argument("-o", "--output", type=Path, default=None)
    parser.add_argument("--smooth", type=int, default=1, help="running-mean window, iterations (1: raw only)")
    parser.add_argument("--title", default=None)
    parser.add_argument("--panels", default="default", choices=sorted(PANEL_SETS), help="which six signals")
    parser.add_argument("--compare", action="store_true",
                        help="the run directories are separate runs, overlaid (not stages of one policy)")
    args = parser.parse_args()
    if args.smooth < 1:
        parser.error(f"--smooth must be >= 1, got {args.smooth}")
    if args.compare:
        rows, starts = {d.name: load(d / "metrics.jsonl") for d in args.run_dirs}, []
    else:
        rows, starts = join_stages([load(d / "metrics.jsonl") for d in args.run_dirs])
    title = args.title or " -> ".join(str(d) for d in args.run_dirs)
    out = plot(rows, args.output or args.run_dirs[-1] / "curves.png", title, starts, args.smooth,
               PANEL_SETS[args.panels])
    what = "run(s) overlaid" if args.compare else "stage(s)"
    print(f"{sum(map(len, rows.values())) if args.compare else len(rows)} iterations in {len(args.run_dirs)} {what} -> {out}")


if __name__ == "__main__":
    main()
