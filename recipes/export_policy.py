"""Slim a training checkpoint down to its policy (for committing or sharing).

    python recipes/export_policy.py outputs/oracle_h1/last.pt checkpoints/oracle_h1.pt
    python recipes/export_policy.py runs/x/last.pt policy.pt --experiment oracle_h1_footholds

A staged experiment exports its policy by itself (``<checkpoint.dir>/policy.pt``), and every run
records its experiment and stage in the meta block; ``--experiment`` / ``--stage`` set them for a
checkpoint trained before runs recorded them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from legoh_rl.training.checkpoint import export_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    parser.add_argument("--experiment", help="the experiment that made it (meta block)")
    parser.add_argument("--stage", help="its stage within that experiment (meta block)")
    args = parser.parse_args()
    provenance = {k: v for k, v in (("experiment", args.experiment), ("stage", args.stage)) if v is not None}
    out = export_policy(args.src, args.dst, provenance)
    print(f"{args.src} ({args.src.stat().st_size / 1e6:.2f} MB) -> {out} ({out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
