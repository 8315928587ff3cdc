"""Depth camera: render time and accuracy of the height-map ray march against MuJoCo's rays.

    python benchmarks/depth_march.py [--samples 8 10 12 16] [--refine 3] [--repeats 5] [--min-only]

For each number of march samples, with and without the lower bracket (the local terrain
minimum): the time of one 64-world 64x64 render on a trail grid of all five categories, and on
five hard tiles (Ditch 3, Gap 4, Forest 2, Hurdle 4, RandomMix 4) the share of pixels within
2 cm and 10 cm of MuJoCo's exact ray casting (``Batch.ray`` against every terrain geom).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from tensordict import TensorDict

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.trail_source import trails_for

CELLS = [("ditch", 3), ("gap", 4), ("forest", 2), ("hurdle", 4), ("randommix", 4)]


def render(env: HikingEnv, ids: np.ndarray, lower: bool) -> np.ndarray:
    w, tr, cam = env.worlds, env.trails, env.built.camera_id
    pos, mat = w.cam_xpos[ids, cam], w.cam_xmat[ids, cam].reshape(-1, 3, 3)
    return env.camera.render(w.batch, pos, mat, ids, tr.height_at_t, tr.ground_height_at_t,
                             z_max=tr.max_height_near(pos[:, :2]),
                             z_min=tr.min_height_near(pos[:, :2]) if lower else None)


def render_ms(samples: int, refine: int, lower: bool, repeats: int) -> float:
    env = HikingEnv(HikingEnvConfig(num_envs=64, mode="student", num_threads=1, levels=(0, 1, 2), seed=0))
    env.camera.cfg.march_samples, env.camera.cfg.march_refine = samples, refine
    env.reset()
    td = TensorDict({"action": torch.zeros(64, env.A)}, batch_size=[64])
    for _ in range(10):
        _, td = env.step_and_maybe_reset(td)
    ids = np.arange(64)
    render(env, ids, lower)
    start = time.perf_counter()
    for _ in range(repeats):
        render(env, ids, lower)
    return (time.perf_counter() - start) / repeats * 1e3


def accuracy(category: str, level: int, samples: int, refine: int, lower: bool) -> tuple[float, float]:
    trails = trails_for((category,), variants=1, seed=1)
    env = HikingEnv(HikingEnvConfig(num_envs=4, mode="student", categories=(category,), levels=(level,),
                                    num_threads=1), trails=trails)
    env.camera.cfg.march_samples, env.camera.cfg.march_refine = samples, refine
    env.reset()
    w = env.worlds
    w.qpos[:, 0] += np.array([0.5, 2.0, 3.5, 5.0])
    w.batch.forward()
    ids = np.arange(4)
    cam = env.built.camera_id
    pos, mat = w.cam_xpos[ids, cam], w.cam_xmat[ids, cam].reshape(-1, 3, 3)
    ref = env.camera.render_exact(w.batch, pos, mat, ids)
    c = env.cfg.depth_camera
    err = np.abs(render(env, ids, lower) - ref) * (c.far - c.near)
    return float(np.mean(err < 0.02)), float(np.mean(err < 0.10))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, nargs="+", default=[8, 10, 12, 16])
    ap.add_argument("--refine", type=int, nargs="+", default=[3])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--min-only", action="store_true", help="only the max+min bracket (the default path)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    head = " | ".join(f"{c}-{lv} (2 cm / 10 cm)" for c, lv in CELLS)
    print(f"| samples | refine | bracket | render ms (64 worlds) | {head} |")
    print("|---:|---:|---|---:|" + "---|" * len(CELLS))
    for s in args.samples:
        for r in args.refine:
            for lower in (True,) if args.min_only else (False, True):
                ms = render_ms(s, r, lower, args.repeats)
                acc = [accuracy(c, lv, s, r, lower) for c, lv in CELLS]
                cells = " | ".join(f"{a * 100:.1f} / {b * 100:.1f}" for a, b in acc)
                print(f"| {s} | {r} | {'max+min' if lower else 'max only'} | {ms:.0f} | {cells} |", flush=True)


if __name__ == "__main__":
    main()
