"""Command line: ``python -m legoh_rl.envs.trails {preview,export,primitive,gallery,table}``.

Examples::

    python -m legoh_rl.envs.trails preview --category forest --level 3 --seed 0 -o forest3.png
    python -m legoh_rl.envs.trails export --category forest --level 3 --seed 0 -o forest3.glb
    python -m legoh_rl.envs.trails export --grid --variants 4 -o grid.glb
    python -m legoh_rl.envs.trails primitive --name gap --level 2 -o gap.png
    python -m legoh_rl.envs.trails gallery --out docs/img/trails
    python -m legoh_rl.envs.trails table
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .config import ALL_CATEGORIES, CATEGORIES, NUM_LEVELS, TrailGridConfig
from .levels import PARAMS

__all__ = ["main", "parameter_table"]


def parameter_table() -> str:
    """Markdown table of every difficulty parameter's range per level."""
    head = (
        "| parameter | unit | "
        + " | ".join(f"level {lv}" for lv in range(NUM_LEVELS))
        + " | meaning |"
    )
    rule = "|---|---|" + "---|" * NUM_LEVELS + "---|"
    rows = [head, rule]
    for p in PARAMS.values():
        cells = []
        for lv in range(NUM_LEVELS):
            lo, hi = p.band(lv)
            cells.append(f"{lo:.3g}-{hi:.3g}")
        rows.append(f"| `{p.name}` | {p.unit} | " + " | ".join(cells) + f" | {p.doc} |")
    return "\n".join(rows)


def _trail_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--category", required=True, help=f"one of: {', '.join(ALL_CATEGORIES)}")
    p.add_argument("--level", type=int, required=True, help=f"0..{NUM_LEVELS - 1}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--variant", type=int, default=0)
    p.add_argument(
        "--length", type=float, default=None, help="tile length, m (default 12, hill 36)"
    )
    p.add_argument("--width", type=float, default=5.0)
    p.add_argument("--resolution", type=float, default=0.1)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m legoh_rl.envs.trails", description="LEGO-H hiking trail generator"
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("preview", help="top-down PNG of one trail")
    _trail_args(p)
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--dpi", type=int, default=80)
    e = sub.add_parser(
        "export", help="mesh (.glb/.obj/.ply/.stl) of one trail, or of a whole grid with --grid"
    )
    e.add_argument(
        "--grid", action="store_true", help="export the whole grid (ignores --category/--level)"
    )
    e.add_argument("--category", default=None, help=f"one of: {', '.join(ALL_CATEGORIES)}")
    e.add_argument("--level", type=int, default=None)
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--variant", type=int, default=0)
    e.add_argument("--variants", type=int, default=4, help="variants per category (with --grid)")
    e.add_argument("--length", type=float, default=None)
    e.add_argument("--width", type=float, default=5.0)
    e.add_argument("--resolution", type=float, default=0.1)
    e.add_argument("-o", "--output", required=True)
    q = sub.add_parser("primitive", help="top-down PNG of one terrain primitive")
    q.add_argument("--name", required=True)
    q.add_argument("--level", type=int, required=True)
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("-o", "--output", required=True)
    g = sub.add_parser(
        "gallery",
        help="the docs images: every primitive at level 2, every category at levels 0 and 4",
    )
    g.add_argument("--out", default="docs/img/trails")
    g.add_argument("--seed", type=int, default=0)
    sub.add_parser("table", help="print the per-level parameter table (markdown)")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (2 with a message on bad arguments)."""
    ap = _parser()
    args = ap.parse_args(argv)
    from .grid import build_trail_grid, single_trail_grid
    from .preview import save_primitive_preview, save_trail_preview
    from .primitives import PRIMITIVES
    from .trail import build_trail

    try:
        if args.cmd == "preview":
            t = build_trail(
                args.category,
                args.level,
                args.seed,
                args.variant,
                args.length,
                args.width,
                args.resolution,
            )
            print(save_trail_preview(t, args.output, dpi=args.dpi))
        elif args.cmd == "export":
            if args.grid:
                grid = build_trail_grid(
                    TrailGridConfig(
                        variants=args.variants, seed=args.seed, resolution=args.resolution
                    )
                )
            else:
                if args.category is None or args.level is None:
                    ap.error("export needs --category and --level (or --grid)")
                grid = single_trail_grid(
                    args.category,
                    args.level,
                    args.seed,
                    args.variant,
                    args.length,
                    args.width,
                    args.resolution,
                )
            print(grid.export(args.output))
        elif args.cmd == "primitive":
            print(save_primitive_preview(args.name, args.level, args.seed, args.output))
        elif args.cmd == "gallery":
            out = Path(args.out)
            for name in PRIMITIVES:
                print(save_primitive_preview(name, 2, args.seed, out / f"primitive_{name}.png"))
            for cat in CATEGORIES:
                for lv in (0, NUM_LEVELS - 1):
                    print(
                        save_trail_preview(
                            build_trail(cat, lv, args.seed), out / f"{cat}_level{lv}.png"
                        )
                    )
            print(save_trail_preview(build_trail("hill", 2, args.seed), out / "hill_level2.png"))
        elif args.cmd == "table":
            print(parameter_table())
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0
