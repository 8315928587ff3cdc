"""Top-down preview images (matplotlib, Agg): height map, pits, obstacles, P_A, P_B, waypoint,
expert goals."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402

from .canvas import TileCanvas  # noqa: E402
from .obstacles import Obstacle, rasterise_tops  # noqa: E402
from .patch import num_samples  # noqa: E402
from .primitives import make_primitive  # noqa: E402
from .trail import Trail  # noqa: E402

__all__ = ["draw_top_down", "save_trail_preview", "save_primitive_preview"]

_FACE = {
    "tree": "#6b4423",
    "log": "#7a5230",
    "hurdle": "#d9822b",
    "rock": "#8a8a8a",
    "boulder": "#77777d",
    "wall": "#5c5040",
    "block": "#6e6253",
}


def draw_top_down(
    ax,
    bare: np.ndarray,
    surface: np.ndarray,
    pit: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    obstacles: list[Obstacle],
    start: np.ndarray | None = None,
    end: np.ndarray | None = None,
    waypoint: np.ndarray | None = None,
    goals: np.ndarray | None = None,
):
    """Draw a height grid (nx, ny) and its annotations on ``ax``; returns the image artist."""
    nx, ny = bare.shape
    x0, y0 = origin
    ext = [
        x0 - resolution / 2,
        x0 + (nx - 0.5) * resolution,
        y0 - resolution / 2,
        y0 + (ny - 0.5) * resolution,
    ]
    ground = bare[~pit] if (~pit).any() else bare.ravel()
    vmin = float(ground.min()) - 0.05
    vmax = max(float(ground.max()), vmin + 0.3) + 0.35
    img = np.ma.masked_array(np.clip(surface, vmin, vmax).T, mask=pit.T)
    cmap = plt.get_cmap("terrain").with_extremes(bad="#1a1a1a")
    im = ax.imshow(
        img, origin="lower", extent=ext, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest"
    )
    for ob in obstacles:
        ax.add_patch(
            Polygon(
                ob.footprint,
                closed=True,
                facecolor=_FACE.get(ob.role, "#665544"),
                edgecolor="k",
                lw=0.4,
                alpha=0.9,
            )
        )
    if goals is not None and start is not None and len(goals):
        route = np.vstack([np.asarray(start)[None, :2], np.asarray(goals)[:, :2]])
        ax.plot(route[:, 0], route[:, 1], "--", color="white", lw=0.8)
        ax.plot(
            goals[:, 0],
            goals[:, 1],
            "o",
            ms=3.0,
            mfc="white",
            mec="black",
            mew=0.5,
            label="expert goals",
        )
    if start is not None:
        ax.plot(start[0], start[1], "o", ms=7, mfc="#22aa22", mec="black", mew=0.6, label="P_A")
    if end is not None:
        ax.plot(end[0], end[1], "*", ms=11, mfc="#dd2222", mec="black", mew=0.6, label="P_B")
    if waypoint is not None:
        ax.plot(
            waypoint[0],
            waypoint[1],
            "D",
            ms=5.5,
            mfc="#ffa500",
            mec="black",
            mew=0.6,
            label="waypoint",
        )
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)
    return im


def _save(fig, path: str | Path, dpi: int) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=dpi)
    plt.close(fig)
    return p


def save_trail_preview(
    trail: Trail, path: str | Path, dpi: int = 80, title: str | None = None
) -> Path:
    """Write a top-down PNG of ``trail`` (about 400 px wide for a 12 m x 5 m tile)."""
    aspect = trail.length / trail.width
    fig_w = 5.0 if aspect < 4 else 8.0
    fig, ax = plt.subplots(figsize=(fig_w, fig_w / aspect + 0.9))
    im = draw_top_down(
        ax,
        trail.heights,
        trail.surface,
        trail.pit,
        trail.origin,
        trail.resolution,
        trail.obstacles,
        trail.start,
        trail.end,
        trail.waypoint,
        trail.goals,
    )
    cb = fig.colorbar(im, ax=ax, fraction=0.03, pad=0.01)
    cb.ax.tick_params(labelsize=6)
    cb.set_label("height (m)", fontsize=6)
    ax.set_title(
        title
        or f"{trail.category} level {trail.level} (seed {trail.seed}, variant {trail.variant})",
        fontsize=8,
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=4, fontsize=6, frameon=False)
    fig.tight_layout()
    return _save(fig, path, dpi)


def save_primitive_preview(
    name: str,
    level: int,
    seed: int,
    path: str | Path,
    width: float = 5.0,
    resolution: float = 0.1,
    dpi: int = 80,
) -> Path:
    """Write a top-down PNG of one primitive between two 1 m flat pads, with its goal spots."""
    patch = make_primitive(name, level, seed, width=width, resolution=resolution)
    pad = num_samples(1.0, resolution)
    cv = TileCanvas((2 * pad + patch.nx) * resolution, width, resolution)
    cv.flat_to(pad)
    spots = cv.place(patch)
    cv.flat_to(cv.nx)
    cv.settle()
    surface = cv.heights.copy()
    origin = (0.0, -width / 2.0)
    rasterise_tops(cv.obstacles, surface, origin, resolution)
    goals = np.array([[s.x, s.y] for s in spots]).reshape(-1, 2)
    aspect = cv.length / width
    fig, ax = plt.subplots(figsize=(5.0, min(3.75, max(2.2, 4.2 / aspect + 0.9))))
    im = draw_top_down(ax, cv.heights, surface, cv.pit, origin, resolution, cv.obstacles)
    if len(goals):
        ax.plot(goals[:, 0], goals[:, 1], "o", ms=3.5, mfc="white", mec="black", mew=0.5)
    cb = fig.colorbar(im, ax=ax, fraction=0.04, pad=0.01)
    cb.ax.tick_params(labelsize=6)
    cb.set_label("height (m)", fontsize=6)
    desc = ", ".join(f"{k}={v:.2f}" for k, v in patch.params.items() if not k.endswith("_realised"))
    ax.set_title(f"{name} level {level}" + (f"\n{desc}" if desc else ""), fontsize=7)
    fig.tight_layout()
    return _save(fig, path, dpi)
