"""Slim a training checkpoint down to its policy (for committing or sharing).

    python recipes/export_policy.py outputs/oracle_h1/last.pt checkpoints/oracle_h1.pt
"""

from __future__ import annotations

import argparse
from pathlib import Path

from legoh_rl.training.checkpoint import export_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    args = parser.parse_args()
    out = export_policy(args.src, args.dst)
    print(f"{args.src} ({args.src.stat().st_size / 1e6:.2f} MB) -> {out} ({out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
