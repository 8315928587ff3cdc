"""Plot learning curves from a recipe's ``metrics.jsonl`` (written beside its checkpoints).

    python recipes/plot_curves.py outputs/oracle_h1 -o docs/img/oracle_h1_curves.png
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


def load(path: Path) -> list[dict]:
    """The rows of a metrics.jsonl file."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot(rows: list[dict], out: Path, title: str) -> Path:
    """Six panels of the main training signals against environment steps."""
    fig, axes = plt.subplots(2, 3, figsize=(12, 6))
    for ax, (key, label) in zip(axes.ravel(), PANELS, strict=True):
        pts = [(r["step"], r[key]) for r in rows if r.get(key) is not None]
        if pts:
            xs, ys = zip(*pts, strict=True)
            ax.plot(xs, ys, lw=1)
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
    parser.add_argument("run_dir", type=Path, help="a recipe's checkpoint.dir (holds metrics.jsonl)")
    parser.add_argument("-o", "--output", type=Path, default=None)
    args = parser.parse_args()
    rows = load(args.run_dir / "metrics.jsonl")
    out = plot(rows, args.output or args.run_dir / "curves.png", str(args.run_dir))
    print(f"{len(rows)} iterations -> {out}")


if __name__ == "__main__":
    main()
