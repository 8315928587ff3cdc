"""Time and memory to generate a trail grid and compile it into a MuJoCo model.

Usage::

    python benchmarks/trail_generation.py                 # 5 categories x 5 levels x 4 variants
    python benchmarks/trail_generation.py --variants 8 --resolution 0.05

Prints generation time (all tiles + assembly), time to add the terrain to an MjSpec, compile
time, peak Python allocations (tracemalloc) and the process's peak RSS, the model's sizes
(nhfielddata, ngeom, nmesh), and the single-thread cost of mj_step with one 50 kg box resting on
every tile (a proxy for the per-world contact cost of the terrain).
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc

import mujoco
import numpy as np

from legoh_rl.envs.trails import CATEGORIES, TrailGridConfig, build_trail_grid


def _box_spec(grid) -> mujoco.MjSpec:
    """A spec with one free 50 kg box (0.4 m) just above every tile's start."""
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.005
    for k, p in enumerate(grid.start.reshape(-1, 3)):
        body = spec.worldbody.add_body(name=f"box{k}", pos=[p[0], p[1], p[2] + 0.25])
        body.add_freejoint()
        g = body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.2, 0.2, 0.2], mass=50.0)
        g.contype, g.conaffinity = 2, 1
    return spec


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--variants", type=int, default=4)
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--no-tracemalloc", action="store_true", help="skip the memory-tracing pass")
    args = ap.parse_args()
    cfg = TrailGridConfig(
        categories=CATEGORIES,
        num_levels=args.levels,
        variants=args.variants,
        resolution=args.resolution,
        seed=args.seed,
    )

    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    t0 = time.perf_counter()
    grid = build_trail_grid(cfg)
    t1 = time.perf_counter()
    spec = _box_spec(grid)
    t2 = time.perf_counter()
    grid.add_to_spec(spec)
    t3 = time.perf_counter()
    model = spec.compile()
    t4 = time.perf_counter()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    # second pass under tracemalloc (which slows Python allocation ~3x: timings above are clean)
    peak_gen = peak_compile = float("nan")
    if not args.no_tracemalloc:
        tracemalloc.start()
        g2 = build_trail_grid(cfg)
        _, peak_gen = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        s2 = _box_spec(g2)
        g2.add_to_spec(s2)
        s2.compile()
        _, peak_compile = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        del g2, s2

    data = mujoco.MjData(model)
    for _ in range(100):  # settle
        mujoco.mj_step(model, data)
    t5 = time.perf_counter()
    for _ in range(args.steps):
        mujoco.mj_step(model, data)
    t6 = time.perf_counter()
    n_tiles = grid.num_rows * grid.num_columns

    print(
        f"grid: {len(CATEGORIES)} categories x {args.levels} levels x {args.variants} variants = {n_tiles} tiles "
        f"of {cfg.tile_length} x {cfg.tile_width} m, resolution {cfg.resolution} m"
    )
    print(
        f"heightfield samples: {grid.map.shape[0]} x {grid.map.shape[1]}; obstacles: {len(grid.obstacles)}"
    )
    print(
        f"generate + assemble: {t1 - t0:.2f} s ({(t1 - t0) / n_tiles * 1e3:.1f} ms/tile); "
        f"add_to_spec: {t3 - t2:.3f} s; compile: {t4 - t3:.3f} s; total {t4 - t0:.2f} s"
    )
    print(
        f"peak Python allocations (tracemalloc): generate {peak_gen / 2**20:.1f} MiB, "
        f"add_to_spec + compile {peak_compile / 2**20:.1f} MiB"
    )
    print(
        f"model: nhfielddata={model.nhfielddata} ngeom={model.ngeom} (terrain {len(grid.terrain_geom_names)}) "
        f"nmesh={model.nmesh}"
    )
    print(
        f"process peak RSS: {rss0:.0f} MiB after imports, {rss1:.0f} MiB after generate + compile"
    )
    per_step = (t6 - t5) / args.steps
    print(
        f"mj_step with {n_tiles} boxes resting on the tiles: {per_step * 1e6:.0f} us/step "
        f"({per_step / n_tiles * 1e6:.1f} us per box)"
    )
    print(
        f"max goals per tile: {int(grid.num_goals.max())}; route length {grid.route_length.min():.1f}-"
        f"{grid.route_length.max():.1f} m; heights {grid.map.bare.min():.2f}..{grid.map.bare.max():.2f} m; "
        f"all finite: {bool(np.isfinite(grid.map.surface).all())}"
    )


if __name__ == "__main__":
    main()
