"""Plot whole-benchmark scores of a run's snapshots against env steps and training hours.

Each point is one evaluation of one snapshot (``recipes/evaluate.py`` on several trail grids):
the ``overall`` rows of its ``table.csv`` (mean ± std over the grids) for success and trail
completion. A series is a list of such tables, one per snapshot; the env steps of a point are
read from the table's file name (``...frames<digits>...``, as the runner names snapshots and as
``docs/history/evals/`` names their tables) or from ``--frames``.

    python recipes/plot_benchmark.py \
        --series "student_h1 raw" docs/history/evals/student_h1_frames00*_grids*.csv \
        --series "student_h1 EMA" docs/history/evals/student_h1_ema_frames00*_grids*.csv \
        --rate 775 775 --reference 54.67 "committed student_h1.pt" -o docs/img/student_h1_benchmark.png

``--rate`` gives each series its env steps/s as measured on an idle machine
(``benchmarks/training_throughput.py``): the hours axis is then env steps / rate, which compares
runs that shared their machine with other work. An entry may instead be the run's directory: each
snapshot is then placed at the run's own training hours when it was taken (its ``metrics.jsonl``,
the iterations' seconds summed as ``plot_curves.py --x hours`` sums them). Without ``--rate`` only
the env-steps panels are drawn.

    python recipes/plot_benchmark.py --series "foot-scan student" docs/history/evals/student_h1_foot_scan_ema_*.csv \
        --series "student_h1, 1 h" docs/history/evals/student_h1_1h_ema_*.csv --rate runs/student_h1_foot_scan 543 -o x.png
"""

from __future__ import annotations

import argparse
import csv
import re
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from legoh_rl.training.run_log import read_metrics, training_hours  # noqa: E402

METRICS = (("success", "success rate (%)"), ("trail_completion", "trail completion (%)"))
_FRAMES = re.compile(r"frames(\d+)")


def read_point(path: Path, frames: int | None = None) -> tuple[int, dict[str, tuple[float, float]]]:
    """One evaluation table as a curve point.

    Args:
        path: a ``table.csv`` of ``recipes/evaluate.py`` (columns ``category, metric, mean, std``).
        frames: the snapshot's env steps; None reads them from ``frames<digits>`` in the file name.

    Returns:
        ``(frames, {metric: (mean, std)})`` for the ``overall`` rows of :data:`METRICS`.

    Raises:
        ValueError: no env steps given or in the name, or the table lacks an ``overall`` row of a
            metric (both name the file).
    """
    if frames is None:
        found = _FRAMES.findall(path.name)
        if not found:
            raise ValueError(f"{path}: no 'frames<digits>' in the file name; pass --frames")
        frames = int(found[-1])
    with path.open(newline="") as f:
        rows = {(r["category"], r["metric"]): r for r in csv.DictReader(f)}
    point = {}
    for metric, _ in METRICS:
        row = rows.get(("overall", metric))
        if row is None:
            raise ValueError(f"{path}: no 'overall,{metric}' row (is it a recipes/evaluate.py table.csv?)")
        point[metric] = (float(row["mean"]), float(row["std"] or 0.0))
    return frames, point


def run_hours(run_dir: Path) -> Callable[[int], float]:
    """``frames -> training hours`` of a run when its iteration ending at those env steps closed
    (the run's ``metrics.jsonl``; :func:`~legoh_rl.training.run_log.training_hours`).

    Raises:
        ValueError: no ``metrics.jsonl`` in ``run_dir`` (names it); the returned function, for env
            steps at which no iteration of the run ended (names both).
    """
    path = Path(run_dir) / "metrics.jsonl"
    if not path.is_file():
        raise ValueError(f"--rate {run_dir}: no metrics.jsonl there (a number or a run directory)")
    rows = read_metrics(path)
    at = {int(r["step"]): h for r, h in zip(rows, training_hours(rows), strict=True)}

    def hours(frames: int) -> float:
        if frames not in at:
            raise ValueError(f"{path}: no iteration ended at {frames} env steps (the snapshot is of another run?)")
        return at[frames]

    return hours


def hours_of(steps: list[int], rate: float | Callable[[int], float]) -> list[float]:
    """The hours axis of a series' points: env steps over an env steps/s, or a run's own hours
    (a function from :func:`run_hours`)."""
    return [rate(f) for f in steps] if callable(rate) else [f / rate / 3600 for f in steps]


def plot(series: dict[str, list[tuple[int, dict]]], out: Path,
         rates: dict[str, float | Callable[[int], float]] | None = None,
         reference: tuple[float, str] | None = None, title: str | None = None) -> Path:
    """Draw success and trail completion (mean ± std error bars) against env steps, and against
    hours when ``rates`` gives each series its env steps/s.

    Args:
        series: label -> points from :func:`read_point` (any order; drawn sorted by env steps).
        out: the PNG to write.
        rates: label -> env steps/s, or a ``frames -> hours`` function (:func:`run_hours`); None:
            env-steps panels only.
        reference: ``(success, label)``: a horizontal line on the success panels.
        title: the figure's title.

    Returns:
        ``out``.
    """
    columns = 2 if rates else 1
    fig, axes = plt.subplots(len(METRICS), columns, figsize=(6.5 * columns, 3.6 * len(METRICS)), squeeze=False)
    for label, points in series.items():
        points = sorted(points, key=lambda p: p[0])
        steps = [p[0] for p in points]
        xs = [(steps, "env steps (M)", 1e-6)]
        if rates:
            xs.append((hours_of(steps, rates[label]), "training hours (each run's own, or env steps / idle env steps/s)", 1.0))
        for row, (metric, name) in enumerate(METRICS):
            mean = [p[1][metric][0] for p in points]
            std = [p[1][metric][1] for p in points]
            for col, (x, xlabel, scale) in enumerate(xs):
                ax = axes[row][col]
                ax.errorbar([v * scale for v in x], mean, yerr=std, marker="o", capsize=3, label=label)
                ax.set_xlabel(xlabel)
                ax.set_ylabel(name)
                ax.grid(alpha=0.3)
    if reference is not None:
        for col in range(columns):
            axes[0][col].axhline(reference[0], color="grey", linestyle="--", label=reference[1])
    for ax in axes.flat:
        ax.legend(fontsize=8)
    fig.suptitle(title or "whole benchmark (5 categories x 5 levels), mean ± std over trail grids")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--series", nargs="+", action="append", required=True, metavar=("LABEL", "CSV"),
                        help="a label, then the table.csv of each evaluated snapshot")
    parser.add_argument("--rate", nargs="+", default=None, metavar="STEPS_PER_S_OR_RUN",
                        help="one per series: its idle env steps/s, or its run directory (the run's own "
                             "training hours at each snapshot); adds the hours panels")
    parser.add_argument("--reference", nargs=2, default=None, metavar=("SR", "LABEL"),
                        help="a success rate to draw as a line, and its label")
    parser.add_argument("--title", default=None)
    parser.add_argument("-o", "--output", type=Path, required=True)
    args = parser.parse_args(argv)
    for entry in args.series:
        if len(entry) < 2:
            parser.error(f"--series needs a label and at least one table.csv, got {entry}")
    labels = [entry[0] for entry in args.series]
    if len(set(labels)) != len(labels):
        parser.error(f"--series labels must differ, got {labels}")
    rates = None
    if args.rate is not None:
        if len(args.rate) != len(labels):
            parser.error(f"--rate needs one entry per series ({len(labels)}), got {args.rate}")
        rates = {}
        for label, entry in zip(labels, args.rate, strict=True):
            try:
                rates[label] = float(entry)
            except ValueError:
                try:
                    rates[label] = run_hours(Path(entry))
                except ValueError as err:
                    parser.error(str(err))
                continue
            if rates[label] <= 0:
                parser.error(f"--rate needs positive env steps/s or a run directory, got {entry}")
    reference = None
    if args.reference is not None:
        try:
            reference = (float(args.reference[0]), args.reference[1])
        except ValueError:
            parser.error(f"--reference needs a number first, got {args.reference[0]!r}")
    series = {entry[0]: [read_point(Path(p)) for p in entry[1:]] for entry in args.series}
    out = plot(series, args.output, rates, reference, args.title)
    print(f"{sum(map(len, series.values()))} evaluations in {len(series)} series -> {out}")
    return out


if __name__ == "__main__":
    main()
