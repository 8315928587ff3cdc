"""The paper's comparison tables, ours beside the paper's numbers (``recipes/paper_tables.py`` is
the command line).

Every table of ``lego-h-paper.tex`` that compares methods (:data:`TABLES`: the ablation on H1 (and again with the students trained to convergence), the
H1 benchmark, GRU vs causal transformers, HLM vs a vanilla VAE, HLM as a plug-in for EP-H, G1 vs
H1, and EP-H vs RMA-B per trail category) lists per method a row of ours (``mean ± std`` of the
six metrics) with the paper's row under it. The modules, in the order the command uses them:

* :mod:`~legoh_rl.paper_tables.paper`: the paper's numbers (:data:`METRICS`, :data:`TABLES`).
* :mod:`~legoh_rl.paper_tables.rows`: which checkpoint holds which method (:data:`ROWS`). A
  student's file is checked against the row before it is used (robot, perception, HLM on or
  off, vanilla VAE, locomotion; :func:`checkpoint_info`, :func:`mismatch`), and a row with
  several matching files (training seeds) is reported as the mean ± std over them
  (:func:`across_seeds`).
* :mod:`~legoh_rl.paper_tables.evaluations`: every checkpoint evaluated once on one protocol
  (:class:`Settings`) by :func:`legoh_rl.training.eval_run.evaluate`; an evaluation of the same
  checkpoint file on the same protocol (its ``evaluated_with.json`` record) is read back instead
  of run again, from the output folder, ``--reuse-from`` folders or an archive
  (``docs/paper_tables/evals`` is the committed one: a fresh checkout rewrites RESULTS.md's
  tables without evaluating again).
* :mod:`~legoh_rl.paper_tables.render`: the tables as markdown and CSV, and into marked
  markdown files (:func:`fill_markers`).
"""

from legoh_rl.paper_tables.evaluations import (
    RowResult,
    Settings,
    archive_evaluation,
    evaluate_checkpoint,
    find_evaluation,
    read_table_csv,
    run_rows,
)
from legoh_rl.paper_tables.paper import (
    METRICS,
    TABLES,
    PaperRow,
    PaperTable,
    Value,
    check_unique,
    table_names,
)
from legoh_rl.paper_tables.render import (
    CSV_FIELDS,
    csv_rows,
    fill_markers,
    fmt,
    into_files,
    markdown,
    write_tables,
)
from legoh_rl.paper_tables.rows import (
    ROWS,
    CheckpointInfo,
    Resolution,
    RowSpec,
    across_seeds,
    checkpoint_info,
    describe,
    mismatch,
    read_info,
    resolve_row,
)

__all__ = [
    "METRICS", "TABLES", "PaperRow", "PaperTable", "Value", "check_unique", "table_names",
    "ROWS", "RowSpec", "CheckpointInfo", "Resolution", "checkpoint_info", "describe", "mismatch", "read_info",
    "resolve_row", "across_seeds",
    "Settings", "RowResult", "find_evaluation", "read_table_csv", "archive_evaluation",
    "evaluate_checkpoint", "run_rows",
    "CSV_FIELDS", "fmt", "markdown", "csv_rows", "write_tables", "fill_markers", "into_files",
]
