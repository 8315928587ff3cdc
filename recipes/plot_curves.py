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
``--panels trails`` plots a whole-benchmark run per category and level (curriculum, success,
trail completion; grouped success smoothed by episode counts) and the gait feedforward gain.
``--compare`` overlays the run directories as separate runs instead, one colour each;
``--align ppo`` counts each one's env steps from the start of its PPO phase, and ``--panels phase``
plots what that phase moves (reward, curriculum, imitation loss, episode metrics).
``--x hours`` plots against training time (the iterations' collection and update seconds summed,
start-ups and evaluations left out; or, with ``--rate``, env steps over each run's env steps/s as
measured on an idle machine in one benchmark run, for runs that shared their machine) instead of env steps: how a GPU run's curve compares with a
CPU run's in time to the same success rate.

    python recipes/plot_curves.py runs/oracle_h1_trails runs/oracle_h1_trails_gpu --compare --x hours \
        --panels trails -o docs/img/oracle_gpu_vs_cpu.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from legoh_rl.training.run_log import read_metrics as load  # noqa: E402
from legoh_rl.training.run_log import training_hours  # noqa: E402

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
CATEGORIES = ("randommix", "ditch", "hurdle", "gap", "forest")
LEVELS = tuple(f"level{lv}" for lv in range(5))
#: whole-benchmark training: a panel may hold several keys (one line each, labelled by its group)
TRAIL_PANELS = [
    ([f"curriculum/{c}" for c in CATEGORIES], "mean terrain level per category"),
    ([f"episode/{c}/success" for c in CATEGORIES], "success per category (%)"),
    ([f"episode/{lv}/success" for lv in LEVELS], "success per level (%)"),
    ([f"episode/{c}/trail_completion" for c in CATEGORIES], "trail completion per category (%)"),
    ("train/gait_feedforward", "gait feedforward gain"),
    ("reward/total", "reward per step"),
]
#: a unified student's PPO phase: how the rollouts (reward, curriculum) and the imitation hold up
PHASE_PANELS = [
    ("reward/total", "reward per step"),
    ("curriculum/mean_level", "mean terrain level"),
    ("loss/im_action", "im_action (SmoothL1 to the teacher)"),
    ("episode/success", "success rate (%)"),
    ("episode/trail_completion", "trail completion (%)"),
    ("episode/ttf", "time to fall (s)"),
]
PANEL_SETS = {"default": PANELS, "gait": GAIT_PANELS, "student": STUDENT_PANELS, "trails": TRAIL_PANELS,
              "phase": PHASE_PANELS}


def since_ppo(rows: list[dict], name: str) -> list[dict]:
    """``rows`` with ``step`` counted from the first iteration of the run's PPO phase (the first row
    with ``train/phase_rl`` > 0; earlier rows get negative steps), so that runs whose PPO phases
    began at different env steps overlay at equal PPO iterations. ``name`` labels the error."""
    start = next((r["step"] for r in rows if (r.get("train/phase_rl") or 0.0) > 0.0), None)
    if start is None:
        raise ValueError(f"{name}: no row with train/phase_rl > 0, so it has no PPO phase to align at")
    # the first PPO row logs the first batch collected in the phase: that batch's start is step 0
    step0 = start - (rows[1]["step"] - rows[0]["step"] if len(rows) > 1 else 0)
    return [{**r, "step": r["step"] - step0} for r in rows]


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


def with_hours(rows: list[dict]) -> list[dict]:
    """``rows`` with ``train/hours`` (:func:`training_hours`) added to each."""
    return [{**r, "train/hours": h} for r, h in zip(rows, training_hours(rows), strict=True)]


def running_mean(ys: list[float], k: int) -> list[float]:
    """Mean of the last ``k`` values at each point (fewer at the start)."""
    out, acc = [], 0.0
    for i, y in enumerate(ys):
        acc += y
        if i >= k:
            acc -= ys[i - k]
        out.append(acc / min(i + 1, k))
    return out


def weighted_running_mean(ys: list[float], ws: list[float], k: int) -> list[float]:
    """Mean of the last ``k`` values weighted by ``ws`` (episode counts) at each point."""
    out = []
    for i in range(len(ys)):
        lo = max(0, i - k + 1)
        w = sum(ws[lo : i + 1])
        out.append(sum(y * v for y, v in zip(ys[lo : i + 1], ws[lo : i + 1], strict=True)) / w if w else float("nan"))
    return out


def _series(run: list[dict], key: str, smooth: int, x: str = "step") -> tuple[list, list, list | None]:
    """``x`` values (env steps), raw values and (when ``smooth`` > 1) their running mean of ``key``;
    a per-group episode metric (``episode/<group>/<metric>``) is averaged weighted by its group's
    episodes."""
    pts = [(r[x], r[key], r.get(key.rsplit("/", 1)[0] + "/episodes", 1.0) or 0.0) for r in run
           if r.get(key) is not None and r[key] == r[key]]
    if not pts:
        return [], [], None
    xs, ys, ws = (list(v) for v in zip(*pts, strict=True))
    if smooth <= 1:
        return xs, ys, None
    grouped = key.startswith("episode/") and key.count("/") == 2
    return xs, ys, weighted_running_mean(ys, ws, smooth) if grouped else running_mean(ys, smooth)


def plot(rows: list[dict] | dict[str, list[dict]], out: Path, title: str, stage_starts: list[float] = (),
         smooth: int = 1, panels: list[tuple] = PANELS, x: str = "step", xlabel: str | None = None) -> Path:
    """Six panels (``panels``: (metrics key or list of keys, title) pairs) of training signals
    against env steps (``x="step"``) or training hours (``x="train/hours"``, rows from
    :func:`with_hours`).

    ``rows``: one run's rows, or ``{label: rows}`` for several runs overlaid (one colour each,
    with a legend). A panel with several keys draws one line per key (one run only). ``xlabel``
    replaces the x axis's default label."""
    runs = rows if isinstance(rows, dict) else {"": rows}
    fig, axes = plt.subplots(2, 3, figsize=(12, 6))
    for ax, (keys, label) in zip(axes.ravel(), panels, strict=True):
        lines = ([(name, run, keys) for name, run in runs.items()] if isinstance(keys, str)
                 else [(key.split("/")[-2] if key.count("/") == 2 else key.split("/")[-1], next(iter(runs.values())), key)
                       for key in keys])
        drawn = 0
        for i, (name, run, key) in enumerate(lines):
            xs, ys, mean = _series(run, key, smooth, x)
            if not xs:
                continue
            drawn += 1
            ax.plot(xs, ys, lw=1, alpha=0.25 if mean is not None else 1.0, color=f"C{i}",
                    label=None if mean is not None or not name else name)
            if mean is not None:
                ax.plot(xs, mean, lw=1.5, color=f"C{i}", label=name or None)
        if len(lines) > 1 and drawn:
            ax.legend(fontsize=7)
        if not drawn:  # e.g. a student's constant gait gain: say so rather than leave empty axes
            ax.text(0.5, 0.5, "not logged by this run", ha="center", va="center", transform=ax.transAxes, color="0.4")
        for start in stage_starts:
            ax.axvline(start, color="k", ls="--", lw=0.8, alpha=0.6)
        ax.set_title(label)
        ax.set_xlabel(xlabel or ("environment steps" if x == "step" else "training hours"))
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
    parser.add_argument("--x", choices=("frames", "hours"), default="frames",
                        help="x axis: env steps, or training hours (collection + update time)")
    parser.add_argument("--rate", type=float, nargs="+", default=None, metavar="STEPS_PER_S",
                        help="with --x hours: one env steps/s per run directory, measured for each on an idle "
                             "machine in one benchmark run; hours are then env steps / rate (the runs' own "
                             "iteration times count whatever else shared the machine)")
    parser.add_argument("--align", choices=("start", "ppo"), default="start",
                        help="with --compare and --x frames: count each run's env steps from its start, or "
                             "from the start of its PPO phase (unified students whose PPO phases began at "
                             "different env steps, compared at equal PPO iterations)")
    args = parser.parse_args()
    if args.rate is not None and (args.x != "hours" or len(args.rate) != len(args.run_dirs)
                                  or any(r <= 0 for r in args.rate)):
        parser.error(f"--rate needs --x hours and one positive rate per run directory ({len(args.run_dirs)}), "
                     f"got {args.rate}")
    if args.smooth < 1:
        parser.error(f"--smooth must be >= 1, got {args.smooth}")
    if args.align == "ppo" and (not args.compare or args.x != "frames"):
        parser.error("--align ppo needs --compare and --x frames")
    if args.compare:
        rows, starts = {d.name: load(d / "metrics.jsonl") for d in args.run_dirs}, []
        if args.align == "ppo":
            try:
                rows = {name: since_ppo(run, name) for name, run in rows.items()}
            except ValueError as err:
                parser.error(str(err))
    else:
        rows, starts = join_stages([load(d / "metrics.jsonl") for d in args.run_dirs])
    x = "step"
    if args.x == "hours":  # stage starts move to the hours of the rows they start at
        x = "train/hours"
        if args.rate is not None:  # hours at a measured rate
            rates = dict(zip([d.name for d in args.run_dirs], args.rate, strict=True)) if args.compare else None
            if args.compare:
                rows = {name: [{**r, x: r["step"] / rates[name] / 3600} for r in run] for name, run in rows.items()}
            else:
                rows = [{**r, x: r["step"] / args.rate[0] / 3600} for r in rows]
                starts = [s / args.rate[0] / 3600 for s in starts]
        elif args.compare:
            rows = {name: with_hours(run) for name, run in rows.items()}
        else:
            rows = with_hours(rows)
            starts = [next(r[x] for r in rows if r["step"] >= s) for s in starts]
    title = args.title or " -> ".join(str(d) for d in args.run_dirs)
    out = plot(rows, args.output or args.run_dirs[-1] / "curves.png", title, starts, args.smooth,
               PANEL_SETS[args.panels], x, "environment steps since the PPO phase began" if args.align == "ppo" else None)
    what = "run(s) overlaid" if args.compare else "stage(s)"
    print(f"{sum(map(len, rows.values())) if args.compare else len(rows)} iterations in {len(args.run_dirs)} {what} -> {out}")


if __name__ == "__main__":
    main()
