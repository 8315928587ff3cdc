"""The hiking benchmark: run a policy on the categories x levels protocol and report the metrics.

Protocol (paper Sec. "Experimental Settings"): ``robots_per_cell`` robots on every
(category, level) cell, each for one episode of at most 30 s (evaluation goal radius 0.89 m,
no randomisation, no curriculum), repeated for ``runs`` seeds. The paper uses 512 robots over
5 categories x 5 levels and 5 runs; the CPU default uses a few robots per cell on the same code
path. Each run's mean per category is one sample; tables report mean +- std over runs.

Why one file of ~500 lines: the rollout and every view of its result (aggregates, tables, CSV,
plot, videos) read the same per-episode records (:func:`_record`), whose layout is kept in one place.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

from legoh_rl.envs.metrics import METRIC_NAMES
from legoh_rl.envs.render import TrackingCamera
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
    "trajectory_figure",
    "category_worlds",
    "render_video",
    "render_videos",
    "VIDEO_CAMERA",
    "release_memory",
    "METRIC_LABELS",
]

#: the videos' camera: 5 m from the torso, 28 degrees down, behind and to the right of a robot
#: walking along +x (as the trails run), looking along its route
VIDEO_CAMERA = TrackingCamera(distance=5.0, elevation=-28.0, azimuth=30.0)

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
            raise ValueError("the protocol needs at least one category and one level, got "
                             f"categories={list(self.categories)}, levels={list(self.levels)}")
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


def release_memory() -> None:
    """Free the memory of the objects just dropped, now: before the next eval env is built.

    Runs the garbage collector (an env's MuJoCo worlds, trails, depth camera and tensors sit in
    reference cycles), then hands the freed heap back to the OS (glibc's ``malloc_trim``; elsewhere
    a no-op): without it, the next env's build does not fit in the holes the last one left, and an
    evaluation's peak memory grows with its number of trail grids (``BENCHMARKS.md``, "Evaluation
    memory"). Close the env (its renderer's OpenGL context) and drop every reference to it (and to
    a policy or result that holds it) before calling this.
    """
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: the allocator keeps what it keeps
        pass


def run_protocol(env, policy, protocol: EvalProtocol, progress: bool = False,
                 hold_finished: bool = True) -> EvalResult:
    """Run ``policy`` (deterministic) on every cell of ``protocol``.

    A world whose counted episode has ended is held (:meth:`~legoh_rl.envs.HikingEnv.hold`)
    until the run's end: its physics, camera and perception stop, which cuts an evaluation's
    time by the share of the 30 s the finished worlds would have spent walking a second episode
    nobody counts. The counted episodes are the same either way.

    Args:
        env: a :class:`~legoh_rl.envs.HikingEnv` in eval mode with ``protocol.num_worlds``
            worlds (or a TransformedEnv around one, e.g. the student's).
        policy: a TensorDictModule writing ``action`` (run under deterministic exploration).
        protocol: the cells, robots and runs.
        progress: show a progress bar of the worlds whose episode has ended (tqdm, on stderr).
        hold_finished: hold the finished worlds (False: step them on, as before the hold existed).

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
                    if hold_finished:
                        base.hold(new)
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
    """Torso paths over their trail, coloured by time (one panel per trail tile), saved as a PNG
    (:func:`trajectory_figure`)."""
    import matplotlib.pyplot as plt

    fig = trajectory_figure(env, result, max_tiles)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def trajectory_figure(env, result: EvalResult, max_tiles: int = 4):
    """The matplotlib figure of :func:`plot_trajectories`: one panel per trail tile (its height map
    in grey, P_A, the expert goals, P_B, and the recorded torso paths coloured by time), laid out
    by matplotlib's constrained layout so no title runs into the panel above."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    base = _base_env(env)
    tr = base.trails
    by_tile: dict[int, list[int]] = {}
    for w, t in result.tiles.items():
        by_tile.setdefault(t, []).append(w)
    tiles = list(by_tile)[:max_tiles]
    fig, axes = plt.subplots(len(tiles), 1, figsize=(6.5, 2.3 * len(tiles) + 0.5), squeeze=False, layout="constrained")
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
            ax.scatter(xy[:, 0], xy[:, 1], c=ts, cmap="viridis", s=3, vmin=0, vmax=tmax)
        ax.set_title(f"{tr.categories[tr.tile_category[t]]}, level {tr.tile_level[t]}", fontsize=10)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_ylabel("y (m)")
    axes[-1, 0].set_xlabel("x (m)")
    time_scale = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0.0, tmax), cmap="viridis")
    fig.colorbar(time_scale, ax=axes[:, 0].tolist(), label="time (s)")
    axes[0, 0].legend(loc="upper left", fontsize=7)
    return fig


def category_worlds(protocol: EvalProtocol, category: str, count: int = 4) -> list[int]:
    """Up to ``count`` worlds of ``category`` in :func:`run_protocol`'s layout, one per level first
    (the first robot of each level's cell, levels in the protocol's order), then the second robot
    of each, and so on: a per-category clip shows the category's levels side by side.

    Raises:
        ValueError: ``category`` is not in the protocol, or ``count`` < 1.
    """
    if category not in protocol.categories:
        raise ValueError(f"category {category!r} is not in the protocol's categories {list(protocol.categories)}")
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    c, n_levels, rpc = protocol.categories.index(category), len(protocol.levels), protocol.robots_per_cell
    order = [(c * n_levels + lv) * rpc + r for r in range(rpc) for lv in range(n_levels)]
    return order[:count]


def render_video(env, policy, path: str | Path, worlds: int | Sequence[int] = 4, seconds: float = 6.0,
                 size: tuple[int, int] = (240, 320), fps: int = 25, progress: bool = False) -> Path | None:
    """A short video of a few robots (tiled two per row): :func:`render_videos` with one clip.

    Args:
        env, policy: as :func:`render_videos`.
        path: the .mp4 to write.
        worlds: how many worlds from world 0, or the world indices.
        seconds, size, fps, progress: as :func:`render_videos`.

    Returns:
        the path, or None with a warning when rendering is unavailable (no OpenGL context: set
        ``MUJOCO_GL=egl`` or ``osmesa`` without a display), so an evaluation never fails on it.
    """
    if not seconds > 0.0:
        raise ValueError(f"video seconds must be positive, got {seconds}")
    if isinstance(worlds, int | np.integer):
        worlds = list(range(min(int(worlds), _base_env(env).cfg.num_envs)))
    written = render_videos(env, policy, {path: worlds}, seconds=seconds, size=size, fps=fps, progress=progress)
    return None if written is None else written[Path(path)]


def render_videos(env, policy, clips: Mapping[str | Path, Sequence[int]], seconds: float = 6.0,
                  size: tuple[int, int] = (240, 320), fps: int = 25, camera=None, route: bool = True,
                  depth_inset: bool = True, progress: bool = True) -> dict[Path, Path] | None:
    """Videos of chosen worlds from one rollout of ``policy``: each clip tiles its worlds two per
    row, every world followed by a camera behind its robot (``camera``, default
    :data:`VIDEO_CAMERA`).

    The frames show the trail (sky, gridded ground in sunlight with shadows, obstacles in
    contrasting colours), the route and goals of each robot (``route``: P_A, the expert goals,
    the goal being walked to in yellow, the waypoint, P_B) and, for a policy that sees depth
    (a student), its latest depth image in the top-right corner (``depth_inset``; near is
    bright). Each world is drawn once per frame, whatever clips show it.

    Args:
        env: the eval env (a HikingEnv, or a TransformedEnv around one), its worlds on their cells.
        policy: the deterministic policy, a TensorDictModule writing ``action``.
        clips: .mp4 path -> world indices shown in it (1 to 4 look best).
        seconds: simulated seconds; ``fps``: frames per second (a frame every
            ``round(1 / (fps * dt))`` control steps).
        size: (height, width) of each world's tile, pixels.
        camera: anything :meth:`~legoh_rl.envs.HikingEnv.render` takes; None is :data:`VIDEO_CAMERA`.
        route: draw the routes and goals; ``depth_inset``: the student's depth image inset.
        progress: a progress bar of the frames drawn (tqdm, on stderr).

    Returns:
        {path: path} of the written clips, or None with a warning when rendering is unavailable.
    """
    import warnings

    from legoh_rl.envs.render import RenderingUnavailableError, inset_image, tile_frames

    if not seconds > 0.0:
        raise ValueError(f"video seconds must be positive, got {seconds}")
    base = _base_env(env)
    n = base.cfg.num_envs
    clips = {Path(p): np.asarray(list(ws), dtype=np.int64).reshape(-1) for p, ws in clips.items()}
    if not clips:
        raise ValueError("no clips to render")
    for p, ws in clips.items():
        if ws.size == 0 or ws.min() < 0 or ws.max() >= n:
            raise ValueError(f"clip {p} must show worlds in [0, {n}), got {ws.tolist()}")
    shown = np.unique(np.concatenate(list(clips.values())))
    row = {int(w): i for i, w in enumerate(shown)}
    every = max(1, int(round(1.0 / (fps * base.dt))))
    steps = int(seconds / base.dt)
    num_frames = len(range(0, steps, every))
    if num_frames == 0:  # shorter than one frame
        warnings.warn(f"video skipped: {seconds} s is shorter than one frame at {fps} fps", stacklevel=2)
        return None
    import imageio.v2 as imageio

    cam = VIDEO_CAMERA if camera is None else camera
    writers: dict[Path, object] = {}
    bar = tqdm(total=num_frames, unit="frames", desc=f"video ({shown.size} robots)", disable=not progress)
    done = False
    td = env.reset()
    try:
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            for step in range(steps):
                td = policy(td)
                _, td = env.step_and_maybe_reset(td)
                if step % every:
                    continue
                tiles = base.render(worlds=shown, width=size[1], height=size[0], camera=cam, route=route)
                depth = td.get("depth", None) if depth_inset else None
                if depth is not None:
                    depth = depth.detach().cpu().numpy()
                    for w, i in row.items():
                        inset_image(tiles[i], depth[w])
                if not writers:
                    for p in clips:
                        p.parent.mkdir(parents=True, exist_ok=True)
                        writers[p] = imageio.get_writer(p, fps=fps, macro_block_size=1)
                for p, ws in clips.items():
                    writers[p].append_data(tile_frames(tiles[[row[int(w)] for w in ws]], cols=2))
                bar.update(1)
        done = True
    except RenderingUnavailableError as err:
        warnings.warn(f"video skipped: {err}", stacklevel=2)
        return None
    finally:
        bar.close()
        for p, writer in writers.items():
            writer.close()
            if not done:
                p.unlink(missing_ok=True)  # no half-written clip
    return {p: p for p in clips}
