"""Command-line arguments shared by the probe recipes (``gait_stats.py``, ``route_following.py``,
``imitation_gap.py``, ``footholds.py``):
a checkpoint rolled out on one (category, level) cell of evaluation trails."""

from __future__ import annotations

import argparse


def probe_parser(description: str, seconds: float) -> argparse.ArgumentParser:
    """A parser with ``checkpoint``, ``--category``, ``--level``, ``--robots``, ``--seconds``
    (default ``seconds``) and ``--seed``; recipes add their own options to it."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint", help="a policy checkpoint, or 'zero' (hold the default pose)")
    parser.add_argument("--category", default="randommix")
    parser.add_argument("--level", type=int, default=0)
    parser.add_argument("--robots", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=seconds)
    parser.add_argument("--seed", type=int, default=0)
    return parser
