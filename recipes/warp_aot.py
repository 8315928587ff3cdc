"""Compile MuJoCo Warp's kernels for a GPU ahead of time, on a machine without one.

    python recipes/warp_aot.py --robot h1 --modes oracle student --arch 90 --out warp_cache
    WARP_CACHE_PATH=warp_cache python recipes/oracle_ppo.py env.physics=warp device=cuda   # on the GPU

A first ``env.physics=warp`` env on a GPU spends its first minute compiling (docs/gpu_physics.md,
"First compile"). Warp's NVRTC compiles CUDA code without a GPU or driver, so this script builds
the env on Warp's CPU device for each mode (the robot and the benchmark's terrain: the model's
collision kernels depend on its geoms), finds every module a step, a reset and the depth camera
launch (``WarpWorlds.record_launches``) and compiles each for ``--arch`` into a Warp kernel cache
(``WarpWorlds.compile_ahead``). A GPU process that points Warp's cache at it (``WARP_CACHE_PATH``)
loads those modules instead of compiling them. ``--arch``: 90 for H100/H200, 80 for A100, 89 for
L4/L40S. Both formats are written by default: Warp loads PTX when the driver is at least as new as
its CUDA toolkit, and CUBIN otherwise.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from legoh_rl.envs import HikingEnv, HikingEnvConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="h1")
    parser.add_argument("--modes", nargs="+", default=["oracle", "student"], choices=["oracle", "student", "eval"])
    parser.add_argument("--arch", type=int, default=90, help="CUDA compute capability (90: H100/H200)")
    parser.add_argument("--formats", nargs="+", default=["cubin", "ptx"], choices=["cubin", "ptx"])
    parser.add_argument("--out", type=Path, default=Path("warp_cache"), help="the kernel cache to write")
    parser.add_argument("--workers", type=int, default=None, help="modules compiled at once (default: one per CPU)")
    args = parser.parse_args()
    written: set[Path] = set()
    for mode in args.modes:
        start = time.perf_counter()
        env = HikingEnv(HikingEnvConfig(robot=args.robot, num_envs=2, mode=mode, physics="warp", device="cpu",
                                        num_threads=1))
        paths = env.worlds.compile_ahead(args.out, arch=args.arch, formats=tuple(args.formats), workers=args.workers)
        written.update(paths)
        print(f"{mode}: {len(paths)} binaries for sm_{args.arch} in {time.perf_counter() - start:.0f} s")
        env.close()
    size = sum(p.stat().st_size for p in written)
    print(f"{args.out}: {len(written)} binaries, {size / 1e6:.1f} MB; on the GPU: WARP_CACHE_PATH={args.out}")


if __name__ == "__main__":
    main()
