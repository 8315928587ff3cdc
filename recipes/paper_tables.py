"""The paper's comparison tables, reproduced from whatever checkpoints are present.

    python recipes/paper_tables.py --trail-seeds 9101 9102 9103
    python recipes/paper_tables.py --trail-seeds 9101 9102 9103 --robots-per-cell 8 --variants 8
    python recipes/paper_tables.py --trail-seeds 9101 9102 --tables ablation g1 --out outputs/tables_h1
    python recipes/paper_tables.py --trail-seeds 9101 --categories randommix --levels 0 --tables ablation
    python recipes/paper_tables.py --trail-seeds 9101 9102 9103 --protocol paper   # 20 robots per cell, 5 runs
    python recipes/paper_tables.py --trail-seeds 9101 9102 9103 --domain-rand --out outputs/tables_dr  # robustness
    python recipes/paper_tables.py --only-paper                                    # the paper's numbers alone

Every table of ``lego-h-paper.tex`` that compares methods is written under ``--out`` as
``<table>.md`` and ``<table>.csv``, with ``tables.md`` holding them all, the command line and the
trail seeds: per method a row of ours (``mean ± std`` of the six metrics) with the paper's row
under it. The tables, rows and figures are :mod:`legoh_rl.paper_tables`; this script is its
command line.

Each method is one or more checkpoints under ``--checkpoints`` (``oracle_h1.pt``,
``student_h1.pt``, ``student_g1.pt``, ``ablations/<robot>_<row>.pt``; every row under
``ablations/`` also takes training seeds, ``ablations/<robot>_<row>_seed<k>.pt``, as the runs of
``recipes/config/experiment/<robot>_<row>.yaml`` with ``env.seed=<k>`` are named). The ablation
rows (LEGO-H, w TC-ViT, Vanilla, ...) read ``ablations/`` alone, trained to one budget, so that
Table 1 compares methods; ``student_h1.pt``, trained longer, is the row "LEGO-H, trained longer"
and each row of ours shows its env steps of training. A student's file is checked against the
row before it is used (robot, perception, HLM on or off, vanilla VAE). A row with several matching files is reported as the mean ± std over them (each
seed's mean over the trail grids, then over seeds). A row with no matching file is listed as
*not trained* with the path that would hold it.

Every checkpoint is evaluated once, as ``recipes/evaluate.py`` evaluates it (its artefacts under
``<out>/evals/<checkpoint>/``), on the same protocol: the categories x levels cells with
``--robots-per-cell`` robots each on ``--variants`` trail variants, repeated on the trail grid of
each of ``--trail-seeds``; for one checkpoint mean ± std is over the trail grids (and runs), as in
``evaluate.py``. An evaluation already in ``--out`` for the same checkpoint file and protocol is
read back rather than run again (``--fresh`` runs everything), so the command can be repeated as
rows are trained; ``--reuse-from DIR`` also takes up ``evaluate.py`` runs made on their own
(``DIR`` an output folder of one, or a folder of them) whose ``evaluated_with.json`` matches.
``--archive DIR`` looks evaluations up in ``DIR`` too and keeps each one there, its record and
``table.csv`` only: ``docs/paper_tables/evals`` is committed, so a fresh checkout rewrites the
tables of RESULTS.md without evaluating the checkpoints again.
The paper's protocol (512 robots, 5 runs) is larger; the comparison is of the same metrics, not
of the same sample.

``--into FILE`` also writes each table into a markdown file that asks for it, between the markers
``<!-- paper_tables:<table> -->`` and ``<!-- /paper_tables:<table> -->`` (RESULTS.md holds its
tables so), keeping everything else in the file as it is.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: off-screen rendering (--video)

import argparse  # noqa: E402
import functools  # noqa: E402
import shlex  # noqa: E402
import sys  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402

from legoh_rl.envs.trails import CATEGORIES, NUM_LEVELS  # noqa: E402
from legoh_rl.paper_tables import (  # noqa: E402
    TABLES,
    Settings,
    evaluate_checkpoint,
    into_files,
    run_rows,
    table_names,
    write_tables,
)


def parser() -> argparse.ArgumentParser:
    """The command line (``--help``)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trail-seeds", type=int, nargs="+", metavar="SEED",
                   help="trail grids to evaluate on, distinct (required unless --only-paper); mean ± std is over them")
    p.add_argument("--tables", nargs="+", metavar="TABLE", default=list(TABLES),
                   help=f"which tables (default all): {', '.join(TABLES)}")
    p.add_argument("--checkpoints", type=Path, default=Path("checkpoints"), help="the checkpoints folder")
    p.add_argument("--out", type=Path, default=Path("outputs/paper_tables"), help="where the tables go")
    p.add_argument("--protocol", default="cpu", help="cpu | paper (20 robots per cell, 5 runs per trail grid)")
    p.add_argument("--robots-per-cell", type=int, default=2, help="robots per (category, level) cell (cpu protocol)")
    p.add_argument("--runs", type=int, default=1, help="runs per trail grid (cpu protocol)")
    p.add_argument("--variants", type=int, default=2, help="trail variants per cell")
    p.add_argument("--categories", nargs="+", default=list(CATEGORIES), help="trail categories")
    p.add_argument("--levels", type=int, nargs="+", default=list(range(NUM_LEVELS)), help="difficulty levels")
    p.add_argument("--device", default="auto", help="where the policies run: auto | cpu | cuda | cuda:<i>")
    p.add_argument("--num-threads", type=int, default=None, help="physics threads (default: evaluate.py's)")
    p.add_argument("--video", action="store_true", help="render evaluate.py's short video of each checkpoint")
    p.add_argument("--logger", default="csv", help="csv | wandb (offline unless configured): each evaluation's log")
    p.add_argument("--domain-rand", action="store_true",
                   help="evaluate under the training's randomisation (a robustness test; the paper's tables are nominal)")
    p.add_argument("--only-paper", action="store_true", help="write the paper's numbers alone; evaluate nothing")
    p.add_argument("--fresh", action="store_true",
                   help="evaluate every checkpoint again, even where --out holds its evaluation on this protocol")
    p.add_argument("--reuse-from", type=Path, nargs="+", default=[],
                   help="evaluate.py output folders (or folders of them) whose evaluations on this protocol to take up")
    p.add_argument("--archive", type=Path, default=None, metavar="DIR",
                   help="also look evaluations up in DIR and keep each one there (its record and table.csv, "
                        "a few kB: docs/paper_tables/evals is the committed one)")
    p.add_argument("--into", type=Path, nargs="+", default=[], metavar="FILE",
                   help="markdown files to write the tables into, between <!-- paper_tables:<table> --> markers "
                        "(the nominal tables: refused with --domain-rand)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (1 when an evaluation failed)."""
    p = parser()
    args = p.parse_args(argv)
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        names = table_names(args.tables)
        settings = None
        if not args.only_paper:
            if args.trail_seeds is None:
                raise ValueError("--trail-seeds is required (several fresh seeds: mean ± std is over the trail grids)")
            settings = Settings(tuple(args.trail_seeds), args.robots_per_cell, args.runs, args.variants,
                                tuple(args.categories), tuple(args.levels), args.protocol, args.device,
                                args.num_threads, args.video, args.logger, args.domain_rand)
            if not args.checkpoints.is_dir():
                raise ValueError(f"--checkpoints {str(args.checkpoints)!r} is not a folder")
            if args.domain_rand and args.into:
                # the markers hold the nominal benchmark: randomised figures there would pass for it
                raise ValueError(f"--domain-rand with --into {[str(f) for f in args.into]}: the marked tables are the "
                                 "nominal benchmark's; write the randomised tables with --out alone")
        into_files(args.into, {}, check_only=True)  # bad files or markers fail before any evaluation
    except ValueError as err:
        p.error(str(err))
    tables = [TABLES[n] for n in names]
    command = "python recipes/paper_tables.py " + shlex.join(argv)
    header = ["# The paper's comparison tables", "", f"Command: `{command.strip()}`", ""]
    if settings is None:
        header += ["The paper's numbers alone (`--only-paper`), from `lego-h-paper.tex`; mean ± std over its 5 runs."]
        written = write_tables(tables, None, args.out, "\n".join(header))
        into_files(args.into, {t.name: written[f"{t.name}.md"].read_text() for t in tables})
        print(f"wrote the paper's numbers of {len(tables)} table(s) to {args.out}")
        return 0
    header += [f"Trail seeds: {', '.join(map(str, settings.trail_seeds))}", "",
               f"Ours: `recipes/evaluate.py`, {settings.describe()}; mean ± std over the trail grids (and runs).",
               "The paper: 512 robots, 30 s, 5 categories x 5 levels, mean ± std over 5 runs.",
               "Each method: a row of ours, the paper's under it. ↑: higher is better, ↓: lower."]
    keys = [r.key for t in tables for r in t.rows]
    results = run_rows(keys, args.checkpoints, settings, args.out,
                       evaluate_fn=functools.partial(evaluate_checkpoint, reuse=not args.fresh,
                                                     reuse_from=tuple(args.reuse_from), archive=args.archive))
    written = write_tables(tables, results, args.out, "\n".join(header))
    into_files(args.into, {t.name: written[f"{t.name}.md"].read_text() for t in tables})
    print("\n" + written["tables.md"].read_text())
    print("written:\n" + "\n".join(f"  {p}" for p in written.values()))
    failed = [k for k, r in results.items() if r.status == "failed"]
    if failed:
        print(f"evaluation failed for {failed}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
