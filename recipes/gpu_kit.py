"""Get a lent GPU machine training within its first minute: the kit, and a tree small enough to send.

A lent machine (docs/gpu_physics.md, "A lent GPU session") starts bare: Python 3.12 with torch and
CUDA, none of this project's other packages, no robot models, and it receives the repository's
working tree (tracked files, untracked files git does not ignore, and the ignored paths a call
carries) only up to 64 MiB in all. This repository's tracked run states alone are far larger, so
a call from a full checkout is refused. This script prepares both, on this machine:

    python recipes/gpu_kit.py build --robot g1              # gpu_kit/: cp312 wheels and the robot's model
    python recipes/gpu_kit.py slim --experiment oracle_g1_real_pits_gpu   # untrack what the job does not read
    python recipes/gpu_kit.py travel --carry gpu_kit        # what a call would send: must be < 64 MiB
    python recipes/gpu_kit.py command --experiment oracle_g1_real_pits_gpu --seconds 480   # the call's command
    ...                                                     # the device calls (carry: gpu_kit)
    python recipes/gpu_kit.py restore                       # track everything again (before any commit)

* ``build`` downloads, for CPython 3.12 on x86-64 Linux and without dependencies, the wheels of
  :data:`KIT_PACKAGES` at the versions installed here (pure-Python ones with no wheel on the
  index are built here), copies the robot's Menagerie folder from ``MENAGERIE_ROOT``, and
  builds the native kernels here (``gpu_kit/native/``, for an image without a C compiler: the
  device loads them through ``LEGOH_RL_NATIVE_PREBUILT`` when their source matches), into the
  ignored folder ``gpu_kit/``.
* ``slim`` takes out of git's index every tracked file under :data:`HEAVY` (run states,
  checkpoints, videos, figures) except those the experiment reads (its run folder, its
  ``checkpoint.init``, its teacher) and lists them in ``.git/info/exclude``, so they stay on disk
  but do not travel. It refuses while anything is staged, and ``restore`` (``git reset`` of those
  paths, the exclude block removed) puts the index back as it was. Commit nothing in between.
* ``travel`` adds up what a call would send: tracked files, untracked files not ignored, and the
  carried paths.
* ``command`` prints the device command: install the kit's wheels, point ``MENAGERIE_ROOT`` at
  its models and ``LEGOH_RL_NATIVE_PREBUILT`` at its kernels, and run ``recipes/gpu_job.py train`` (which packs the run's state into ``$OUT``).
"""

from __future__ import annotations

import argparse
import shutil
import sys

from legoh_rl.envs.native.build import export_library
from legoh_rl.training.gpu_kit import (
    HEAVY,
    KIT,
    KIT_PACKAGES,
    ROOT,
    TRAVEL_LIMIT,
    WARP_PACKAGES,
    copy_robot,
    device_command,
    download_wheels,
    needed_paths,
    pinned,
    restore,
    slim,
    split_large,
    travel_bytes,
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="wheels and robot models into gpu_kit/")
    b.add_argument("--robot", nargs="+", default=["h1"], choices=["h1", "g1"])
    b.add_argument("--warp", action="store_true", help="add mujoco-warp and warp-lang (env.physics=warp)")
    b.add_argument("--part-mib", type=int, default=48, help="split wheels over this size into parts")
    s = sub.add_parser("slim", help="untrack what the experiment does not read")
    s.add_argument("--experiment", required=True)
    s.add_argument("--keep", nargs="*", default=[], help="more tracked paths to send")
    sub.add_parser("restore", help="track again what slim untracked")
    t = sub.add_parser("travel", help="what a device call would send")
    t.add_argument("--carry", nargs="*", default=[])
    c = sub.add_parser("command", help="print the device command")
    c.add_argument("--experiment", required=True)
    c.add_argument("--seconds", type=int, default=480)
    c.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    if args.command == "build":
        kit = ROOT / KIT
        for old in ("wheels", "robots", "native"):  # nothing of an earlier build stays (a wheel, part, robot)
            shutil.rmtree(kit / old, ignore_errors=True)
        wheels = download_wheels(pinned(KIT_PACKAGES + (WARP_PACKAGES if args.warp else ())), kit / "wheels")
        files = split_large(wheels, args.part_mib * 2**20)
        robots = [copy_robot(r, kit / "robots") for r in args.robot]
        native = export_library(kit / "native")
        size = sum(f.stat().st_size for f in kit.rglob("*") if f.is_file())
        print(f"{kit}: {len(files)} wheel file(s), robots {[r.name for r in robots]}, "
              f"kernels {native.name}, {size / 2**20:.1f} MiB")
    elif args.command == "slim":
        keep = needed_paths(args.experiment) + list(args.keep)
        dropped = slim(keep)
        print(f"excluded {len(dropped)} file(s) under {', '.join(HEAVY)}; kept {keep}. "
              "Commit nothing until: python recipes/gpu_kit.py restore")
    elif args.command == "restore":
        print(f"tracked {len(restore())} file(s) again; the exclude block is gone")
    elif args.command == "travel":
        t = travel_bytes(args.carry)
        mib = {k: round(v / 2**20, 1) for k, v in t.items() if k != "fits"}
        print(f"a call sends {mib} MiB: {'within' if t['fits'] else 'OVER'} the {TRAVEL_LIMIT // 2**20} MiB limit")
        return 0 if t["fits"] else 1
    else:
        print(device_command(args.experiment, args.seconds, args.overrides))
    return 0


if __name__ == "__main__":
    sys.exit(main())
