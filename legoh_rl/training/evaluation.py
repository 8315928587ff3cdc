"""The hiking benchmark: run a policy on the categories x levels protocol and report the metrics.

Protocol (paper Sec. "Experimental Settings"): ``robots_per_cell`` robots on every
(category, level) cell, each for one episode of at most 30 s (evaluation goal radius 0.89 m,
no randomisation, no curriculum), repeated for ``runs`` seeds. The paper uses 512 robots over
5 categories x 5 levels and 5 runs; the CPU default uses a few robots per cell on the same code
path. Each run's mean per category is one sample; tables report mean +- std over runs.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from legoh_rl.envs.metrics import METRIC_NAMES
from legoh_rl.envs.trails import ALL_CATEGORIES, NUM_LEVELS

__all__ = [
    "EvalProtocol",
    "EvalResult",
    "run_protocol",
    "eval_scalars",
    "long_table",
    "aggregate",
    "markdown_table",
    "cell_table",
    "write_csv",
    "write_episodes",
    "plot_trajectories",
    "render_video",
    "METRIC_LABELS",
]

METRIC_LABELS = {
    "success": "Success Rate (%)",
    "trail_completion": "Trail Completion (%)",
    "traverse_rate": "Traverse Rate (%)",
    "mev": "MEV (%)",
    "ttf": "TTF (s)",
    "time_to_reach": "Time-to-Reach (s)",
}


@dataclass
class EvalProtocol:
    """Which cells, how many robots, how many runs.

    Attributes:
        categories: category names (must be in the env's trail grid).
        levels: difficulty levels.
        robots_per_cell: robots on each (category, level) cell.
        runs: repetitions with different seeds.
        seed: seed of run 0 (run r uses ``seed + r``).
        trajectories: worlds whose base path is recorded in run 0 (for the plot).
    """

    categories: tuple[str, ...]
    levels: tuple[int, ...]
    robots_per_cell: int = 4
    runs: int = 1
    seed: int = 0
    trajectories: int = 16

    def __post_init__(self) -> None:
        if self.robots_per_cell < 1 or self.runs < 1:
            raise ValueError(f"robots_per_cell and runs must be >= 1, got {self.robots_per_cell}, {self.runs}")
        if not self.categories or not self.levels:
            raise ValueError("the protocol needs at least one category and one level")
        for name, values in (("categories", list(self.categories)), ("levels", list(self.levels))):
            repeated = sorted({v for v in values if values.count(v) > 1}, key=str)
            if repeated:
                raise ValueError(f"{name} must be distinct, got {values} (repeated: {repeated})")
        unknown = [c for c in self.categories if c not in ALL_CATEGORIES]
        if unknown:
            raise ValueError(f"unknown categories {unknown}; valid: {list(ALL_CATEGORIES)}")
        outside = [lv for lv in self.levels if not 0 <= int(lv) < NUM_LEVELS]
        if outside:
            raise ValueError(f"levels {outside} out of range; valid: 0..{NUM_LEVELS - 1}")

    @property
    def num_worlds(self) -> int:
        """Worlds the eval env must have: robots_per_cell x categories x levels."""
        return self.robots_per_cell * len(self.categories) * len(self.levels)


@dataclass
class EvalResult:
    """Per-episode records and the recorded trajectories.

    Attributes:
        episodes: one dict per episode: run, category, level, and the six metrics.
        trajectories: world -> (T, 2) base xy of run 0, with ``tiles`` world -> tile index.
        times: world -> (T,) time of each trajectory sample, s.
    """

    episodes: list[dict] = field(default_factory=list)
    trajectories: dict[int, np.ndarray] = field(default_factory=dict)
    times: dict[int, np.ndarray] = field(default_factory=dict)
    tiles: dict[int, int] = field(default_factory=dict)


def _base_env(env):
    return getattr(env, "base_env", env)


def run_protocol(env, policy, protocol: EvalProtocol, progress: bool = False) -> EvalResult:
    """Run ``policy`` (deterministic) on every cell of ``protocol``.

    Args:
        env: a :class:`~legoh_rl.envs.HikingEnv` in eval mode with ``protocol.num_worlds``
            worlds (or a TransformedEnv around one, e.g. the student's).
        policy: a TensorDictModule writing ``action`` (run under deterministic exploration).
        protocol: the cells, robots and runs.
        progress: show a progress bar of the worlds whose episode has ended (tqdm, on stderr).

    Returns:
        the :class:`EvalResult`; each world contributes the first episode of each run.
    """
    base = _base_env(env)
    n = base.cfg.num_envs
    if n != protocol.num_worlds:
        raise ValueError(f"the eval env has {n} worlds, the protocol needs {protocol.num_worlds}")
    cat_index = {name: i for i, name in enumerate(base.trails.categories)}
    unknown = [c for c in protocol.categories if c not in cat_index]
    if unknown:
        raise ValueError(f"categories {unknown} are not in the env's trails {list(base.trails.categories)}")
    cells = [(c, lv) for c in protocol.categories for lv in protocol.levels]
    cell_of = np.repeat(np.arange(len(cells)), protocol.robots_per_cell)
    cats = np.array([cat_index[cells[k][0]] for k in cell_of])
    levels = np.array([cells[k][1] for k in cell_of])
    result = EvalResult()
    max_steps = base.max_steps + 2
    bar = tqdm(total=n * protocol.runs, unit="episodes", desc="evaluation", disable=not progress)
    for run in range(protocol.runs):
        env.set_seed(protocol.seed + run)
        base.assign_tiles(levels, cats)
        td = env.reset()
        finished = np.zeros(n, dtype=bool)
        track = np.arange(min(protocol.trajectories, n)) if run == 0 else np.arange(0)
        paths = [base.worlds.qpos[track, :2].copy()]
        if run == 0:
            result.tiles = {int(w): int(base.tile[w]) for w in track}
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            for _ in range(max_steps):
                td = policy(td)
                out, td = env.step_and_maybe_reset(td)
                done = out["next", "done"].reshape(n).cpu().numpy()
                new = done & ~finished
                if new.any():
                    _record(result, out["next"], new, run, cells, cell_of)
                    bar.update(int(new.sum()))
                if track.size:  # a world that just ended was auto-reset: its path stops here
                    ended = (finished | done)[track, None]
                    paths.append(np.where(ended, np.nan, base.worlds.qpos[track, :2]))
                finished |= done
                if finished.all():
                    break
        if not finished.all():
            raise RuntimeError(f"{int((~finished).sum())} worlds did not finish within {max_steps} steps")
        if track.size:
            xy = np.stack(paths, axis=1)  # (k, T, 2)
            for i, w in enumerate(track):
                keep = ~np.isnan(xy[i, :, 0])
                result.trajectories[int(w)] = xy[i, keep]
                result.times[int(w)] = np.arange(xy.shape[1])[keep] * base.dt
    bar.close()
    return result


def _record(result: EvalResult, nxt: TensorDictBase, new: np.ndarray, run: int, cells, cell_of) -> None:
    ep = {name: nxt["episode", name].reshape(-1).cpu().numpy() for name in METRIC_NAMES}
    for w in np.flatnonzero(new):
        cat, level = cells[cell_of[w]]
        result.episodes.append({"run": run, "category": cat, "level": int(level),
                                **{k: float(v[w]) for k, v in ep.items()}})


def eval_scalars(rows: dict[str, dict[str, tuple[float, float]]], prefix: str = "eval") -> dict[str, float]:
    """The figures of :func:`aggregate` as numbers: ``{prefix}/<group>/<metric>`` (the mean) and
    ``{prefix}/<group>/<metric>_std``, groups with spaces as underscores (``level_0``)."""
    out = {}
    for group, metrics in rows.items():
        g = group.replace(" ", "_")
        for m, (mean, std) in metrics.items():
            out[f"{prefix}/{g}/{m}"] = mean
            out[f"{prefix}/{g}/{m}_std"] = std
    return out


def long_table(rows: dict[str, dict[str, tuple[float, float]]], by: str) -> tuple[list[str], list[list]]:
    """(columns, data) of :func:`aggregate`'s figures, one numeric row per group and metric:
    ``[by, group, metric, mean, std]`` (sortable and plottable, e.g. as a wandb Table)."""
    data = [[by, group, m, float(mean), float(std)] for group, metrics in rows.items()
            for m, (mean, std) in metrics.items()]
    return ["by", "group", "metric", "mean", "std"], data


def _mean(values: list[float]) -> float:
    vals = [v for v in values if not math.isnan(v)]
    return float(np.mean(vals)) if vals else math.nan


def aggregate(episodes: list[dict], by: str = "category") -> dict[str, dict[str, tuple[float, float]]]:
    """Mean +- std over runs of each run's per-group mean, per group and overall.

    Time-to-Reach averages successful episodes only (NaN when none succeeded). The std is the
    population std over runs (0 for a single run).

    Args:
        episodes: :attr:`EvalResult.episodes`.
        by: ``"category"`` (rows named after the categories) or ``"level"`` (rows
            ``"level 0"``, ``"level 1"``, ...).

    Returns:
        {row: {metric: (mean, std)}} with one row per group and ``"overall"``.
    """
    if by not in ("category", "level"):
        raise ValueError(f"by must be 'category' or 'level', got {by!r}")

    def name(value) -> str:
        return f"level {value}" if by == "level" else str(value)

    rows: dict[str, dict[str, tuple[float, float]]] = {}
    groups = [name(v) for v in sorted({e[by] for e in episodes})] + ["overall"]
    runs = sorted({e["run"] for e in episodes})
    for g in groups:
        sel = [e for e in episodes if g == "overall" or name(e[by]) == g]
        rows[g] = {}
        for m in METRIC_NAMES:
            per_run = [_mean([e[m] for e in sel if e["run"] == r]) for r in runs]
            finite = [v for v in per_run if not math.isnan(v)]
            rows[g][m] = (float(np.mean(finite)), float(np.std(finite))) if finite else (math.nan, math.nan)
    return rows


def cell_table(episodes: list[dict], metric: str = "success") -> str:
    """``metric`` per (category, level) cell as a markdown table (rows = categories, columns =
    levels and "all"), each cell the mean +- std over runs of the run's cell mean."""
    cats = sorted({e["category"] for e in episodes}, key=lambda c: [e["category"] for e in episodes].index(c))
    levels = sorted({e["level"] for e in episodes})
    runs = sorted({e["run"] for e in episodes})

    def cell(sel: list[dict]) -> str:
        per_run = [_mean([e[metric] for e in sel if e["run"] == r]) for r in runs]
        finite = [v for v in per_run if not math.isnan(v)]
        return f"{np.mean(finite):.1f} ± {np.std(finite):.1f}" if finite else "-"

    lines = [f"| {metric} | " + " | ".join(f"level {lv}" for lv in levels) + " | all |",
             "|---|" + "---:|" * (len(levels) + 1)]
    for c in cats:
        mine = [e for e in episodes if e["category"] == c]
        lines.append(f"| {c} | " + " | ".join(cell([e for e in mine if e["level"] == lv]) for lv in levels)
                     + f" | {cell(mine)} |")
    return "\n".join(lines)


def write_episodes(episodes: list[dict], path: str | Path) -> Path:
    """Every episode's record (run, trail seed, category, level, the six metrics) as CSV."""
    path = Path(path)
    keys = list(dict.fromkeys(k for e in episodes for k in e if not isinstance(e[k], (list, tuple, np.ndarray))))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(episodes)
    return path


def markdown_table(rows: dict[str, dict[str, tuple[float, float]]]) -> str:
    """The aggregate as a markdown table (rows = metrics, columns = the groups + overall)."""
    cols = list(rows)
    lines = ["| metric | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for m in METRIC_NAMES:
        cells = []
        for c in cols:
            mean, std = rows[c][m]
            cells.append("n/a" if math.isnan(mean) else f"{mean:.2f} ± {std:.2f}")
        lines.append(f"| {METRIC_LABELS[m]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_csv(rows: dict[str, dict[str, tuple[float, float]]], path: str | Path) -> Path:
    """One line per (row, metric): ``row,metric,mean,std``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["category", "metric", "mean", "std"])
        for row, metrics in rows.items():
            for m, (mean, std) in metrics.items():
                w.writerow([row, m, mean, std])
    return path


def plot_trajectories(env, result: EvalResult, path: str | Path, max_tiles: int = 4) -> Path:
    """Torso paths over their trail, coloured by time (one panel per trail tile)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    base = _base_env(env)
    tr = base.trails
    by_tile: dict[int, list[int]] = {}
    for w, t in result.tiles.items():
        by_tile.setdefault(t, []).append(w)
    tiles = list(by_tile)[:max_tiles]
    fig, axes = plt.subplots(len(tiles), 1, figsize=(8, 2.6 * len(tiles)), squeeze=False)
    tmax = max((ts[-1] for ts in result.times.values() if ts.size), default=1.0)
    for ax, t in zip(axes[:, 0], tiles, strict=False):
        start, end = tr.tile_start[t], tr.tile_end[t]
        x0, x1 = min(start[0], end[0]) - 1.5, max(start[0], end[0]) + 1.5
        y0, y1 = min(start[1], end[1]) - 3.0, max(start[1], end[1]) + 3.0
        xs, ys = np.meshgrid(np.linspace(x0, x1, 240), np.linspace(y0, y1, 80))
        h = tr.height_at(np.stack([xs.ravel(), ys.ravel()], -1)).reshape(xs.shape)
        ax.imshow(h, extent=(x0, x1, y0, y1), origin="lower", cmap="gray", aspect="equal")
        goals = tr.tile_goals[t, : tr.tile_num_goals[t]]
        ax.plot(goals[:, 0], goals[:, 1], "c.", ms=4, label="expert goals")
        ax.plot(*start[:2], "g^", ms=8, label="P_A")
        ax.plot(*end[:2], "r*", ms=10, label="P_B")
        for w in by_tile[t]:
            xy, ts = result.trajectories[w], result.times[w]
            sc = ax.scatter(xy[:, 0], xy[:, 1], c=ts, cmap="viridis", s=3, vmin=0, vmax=tmax)
        ax.set_title(f"{tr.categories[tr.tile_category[t]]}, level {tr.tile_level[t]}")
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
    fig.colorbar(sc, ax=axes[:, 0].tolist(), label="time (s)")
    axes[0, 0].legend(loc="upper left", fontsize=7)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def render_video(env, policy, path: str | Path, worlds: int = 4, seconds: float = 6.0,
                 size: tuple[int, int] = (240, 320), fps: int = 25) -> Path | None:
    """A short video of the first ``worlds`` robots (tiled two per row), each followed by a
    camera tracking its torso (:meth:`~legoh_rl.envs.HikingEnv.render`).

    Args:
        env: the eval env (a HikingEnv, or a TransformedEnv around one), its worlds on their cells.
        policy: the deterministic policy, a TensorDictModule writing ``action``.
        path: the .mp4 to write.
        worlds: how many worlds (from world 0); ``size``: (height, width) of each tile, pixels.
        seconds: simulated seconds; ``fps``: frames per second of the video.

    Returns:
        the path, or None with a warning when rendering is unavailable (no OpenGL context: set
        ``MUJOCO_GL=egl`` or ``osmesa`` without a display), so an evaluation never fails on it.
    """
    import warnings

    from legoh_rl.envs.render import RenderingUnavailableError, tile_frames

    if not seconds > 0.0:
        raise ValueError(f"video seconds must be positive, got {seconds}")
    import imageio.v2 as imageio

    base = _base_env(env)
    ids = list(range(min(worlds, base.cfg.num_envs)))
    every = max(1, int(round(1.0 / (fps * base.dt))))
    frames = []
    td = env.reset()
    try:
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            for step in range(int(seconds / base.dt)):
                td = policy(td)
                _, td = env.step_and_maybe_reset(td)
                if step % every == 0:
                    tiles = base.render(worlds=ids, width=size[1], height=size[0])
                    frames.append(tile_frames(tiles, cols=2))
    except RenderingUnavailableError as err:
        warnings.warn(f"video skipped: {err}", stacklevel=2)
        return None
    if not frames:  # shorter than one frame
        warnings.warn(f"video skipped: {seconds} s is shorter than one frame at {fps} fps", stacklevel=2)
        return None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    imageio.mimsave(path, frames, fps=fps, macro_block_size=1)
    return path
