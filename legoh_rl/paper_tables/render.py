"""Writing the tables: each table as markdown (ours and the paper's row under it, :func:`markdown`)
and CSV records (:func:`csv_rows`), the files of a table set (:func:`write_tables`), and the tables
put into a markdown file between its markers (:func:`fill_markers`, :func:`into_files`)."""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from legoh_rl.paper_tables.evaluations import RowResult
from legoh_rl.paper_tables.paper import METRICS, TABLES, PaperRow, PaperTable, Value, check_unique

__all__ = ["fmt", "env_steps", "contrast", "markdown", "csv_rows", "CSV_FIELDS", "write_tables", "fill_markers", "into_files"]


def fmt(value: Value | None) -> str:
    """``"mean ± std"`` with two decimals (as the paper), ``"n/a"`` for NaN, ``"—"`` for None."""
    if value is None:
        return "—"
    mean, std = value
    if math.isnan(mean):
        return "n/a"
    return f"{mean:.2f} ± {std:.2f}"


def env_steps(frames: Sequence[int | None]) -> str:
    """A row's training budget: ``"1.70M"`` (one checkpoint, or several seeds with the same
    budget), ``"1.70M-1.72M"`` (seeds that differ), ``"—"`` when no checkpoint recorded it."""
    known = sorted(int(f) for f in frames if f is not None)
    if not known:
        return "—"
    lo, hi = f"{known[0] / 1e6:.2f}M", f"{known[-1] / 1e6:.2f}M"
    return lo if lo == hi else f"{lo}-{hi}"


def _ours(row: PaperRow, result: RowResult | None) -> tuple[str, dict[str, Value | None], str]:
    """(status, our figures, checkpoint cell) of a table row."""
    if result is None:
        return "missing", dict.fromkeys(METRICS), ""
    if result.status == "not trained":
        note = f"; {result.note}" if result.note else ""
        return "not trained", dict.fromkeys(METRICS), f"not trained: `{result.path}`{note}"
    if result.status == "failed":
        return "failed", dict.fromkeys(METRICS), f"evaluation failed: `{result.path}`: {result.note}"
    where = f"`{result.path}`"
    if len(result.paths) > 1:
        where = (", ".join(f"`{p}`" for p in result.paths)
                 + f" ({len(result.paths)} training seeds: mean ± std over seeds)")
    group = (result.rows or {}).get(row.group)
    if group is None:
        return ("not evaluated", dict.fromkeys(METRICS), f"{where}: {row.group} not among the evaluated categories")
    return "evaluated", {m: group[m] for m in METRICS}, where


def contrast(a: RowResult | None, b: RowResult | None, metric: str = "success") -> dict | None:
    """Row a minus row b in ``metric`` over their training seeds (each seed's mean over the trail
    grids), with Welch's t and Cohen's d (pooled sample std) when each row has two seeds or more.

    Returns:
        ``{"diff", "t", "d", "n_a", "n_b"}`` (``t``, ``d``: None with fewer than two seeds on
        either side, or no spread at all), or None when either row was not evaluated.
    """
    if a is None or b is None or a.status != "evaluated" or b.status != "evaluated":
        return None
    xa = np.array([seed["overall"][metric][0] for seed in a.per_seed], float)
    xb = np.array([seed["overall"][metric][0] for seed in b.per_seed], float)
    out = {"diff": float(xa.mean() - xb.mean()), "t": None, "d": None, "n_a": len(xa), "n_b": len(xb)}
    if len(xa) >= 2 and len(xb) >= 2:
        va, vb = xa.var(ddof=1), xb.var(ddof=1)
        if va + vb > 0:
            out["t"] = out["diff"] / math.sqrt(va / len(xa) + vb / len(xb))
            out["d"] = out["diff"] / math.sqrt((va + vb) / 2)
    return out


def _contrast_lines(table: PaperTable, results: Mapping[str, RowResult]) -> list[str]:
    """The table's contrasts as markdown bullets (ours beside the paper's difference)."""
    paper = {r.key: r.paper for r in table.rows if r.paper is not None}
    lines = []
    for what, ka, kb in table.contrasts:
        names = {r.key: r.method for r in table.rows}
        head = f"- {what} ({names[ka]} - {names[kb]}), SR points: "
        theirs = (f"paper {paper[ka]['success'][0] - paper[kb]['success'][0]:+.2f}"
                  if ka in paper and kb in paper else "paper —")
        c = contrast(results.get(ka), results.get(kb))
        if c is None:
            lines.append(head + f"ours — (a row not evaluated); {theirs}")
            continue
        seeds = f"{c['n_a']} vs {c['n_b']} training seeds"
        stats = (f", Welch's t = {c['t']:.2f}, Cohen's d = {c['d']:.2f}" if c["t"] is not None
                 else ": too few seeds for a t")
        lines.append(head + f"ours {c['diff']:+.2f} ({seeds}{stats}); {theirs}")
    return lines


def markdown(table: PaperTable, results: Mapping[str, RowResult] | None) -> str:
    """One table as markdown: per method a row of ours and the paper's under it.

    Args:
        table: the table.
        results: {row key: :class:`~legoh_rl.paper_tables.evaluations.RowResult`}, or None for the paper's rows alone.

    Returns:
        the markdown (a heading, the note if any, the table).
    """
    grouped = any(r.group != "overall" for r in table.rows)
    head = ["method"] + (["trails"] if grouped else []) + ["source"]
    head += [] if results is None else ["env steps"]
    head += [METRICS[m][0] for m in METRICS] + ([] if results is None else ["checkpoint"])
    lines = [f"### {table.caption} (`{table.label}`)", ""]
    if table.note:
        lines += [table.note, ""]
    lines += ["| " + " | ".join(head) + " |",
              "|" + "|".join("---:" if h in [v[0] for v in METRICS.values()] else "---" for h in head) + "|"]
    for row in table.rows:
        trails = [row.group] if grouped else []
        if results is not None:
            res = results.get(row.key)
            status, ours, where = _ours(row, res)
            cells = [fmt(ours[m]) for m in METRICS] if status == "evaluated" else [status] + ["—"] * (len(METRICS) - 1)
            steps = env_steps(res.frames if res is not None else ())
            lines.append("| " + " | ".join([row.method, *trails, "ours", steps, *cells, where]) + " |")
        if row.paper is not None:
            name = "" if results is not None else row.method
            lines.append("| " + " | ".join([name, *trails, "paper", *([""] if results is not None else []),
                                            *(fmt(row.paper[m]) for m in METRICS)]
                                           + ([""] if results is not None else [])) + " |")
    if results is not None and table.contrasts:
        lines += ["", "Effects:", "", *_contrast_lines(table, results)]
    return "\n".join(lines)


def csv_rows(table: PaperTable, results: Mapping[str, RowResult] | None) -> list[dict]:
    """One table as CSV records: per method one ``ours`` record (unless ``results`` is None) and
    one ``paper`` record (when the paper has the row), each with ``<metric>_mean``/``_std``
    (empty when there is no figure) and ``status``/``checkpoint``/``env_steps``/``note`` (a
    row's training seeds' checkpoints and their env steps of training joined by ``;``)."""
    out = []
    for row in table.rows:
        base = {"table": table.name, "label": table.label, "method": row.method, "row": row.key, "trails": row.group}
        if results is not None:
            res = results.get(row.key)
            status, ours, _ = _ours(row, res)
            where = "" if res is None else ";".join(str(q) for q in (res.paths or (res.path,)))
            steps = "" if res is None else ";".join("" if f is None else str(f) for f in res.frames)
            rec = {**base, "source": "ours", "status": status, "checkpoint": where, "env_steps": steps,
                   "note": res.note if res else ""}
            out.append(_with_metrics(rec, ours))
        if row.paper is not None:
            out.append(_with_metrics({**base, "source": "paper", "status": "paper", "checkpoint": "", "env_steps": "",
                                      "note": ""},
                                     row.paper))
    return out


CSV_FIELDS = (["table", "label", "method", "row", "trails", "source", "status"]
              + [f"{m}_{s}" for m in METRICS for s in ("mean", "std")] + ["checkpoint", "env_steps", "note"])


def _with_metrics(rec: dict, values: Mapping[str, Value | None]) -> dict:
    for m in METRICS:
        v = values.get(m)
        rec[f"{m}_mean"], rec[f"{m}_std"] = ("", "") if v is None else v
    return rec


def write_tables(tables: Sequence[PaperTable], results: Mapping[str, RowResult] | None, out: Path,
                 header: str) -> dict[str, Path]:
    """Write ``<table>.md`` and ``<table>.csv`` per table and ``tables.md`` (``header``, the tables,
    and the checkpoint of every row) under ``out``.

    Returns:
        {file name: path} of everything written.
    """
    out.mkdir(parents=True, exist_ok=True)
    written, parts = {}, [header]
    for table in tables:
        md = markdown(table, results)
        parts.append(md)
        written[f"{table.name}.md"] = out / f"{table.name}.md"
        written[f"{table.name}.md"].write_text(md + "\n")
        path = out / f"{table.name}.csv"
        with open(path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            writer.writeheader()
            writer.writerows(csv_rows(table, results))
        written[path.name] = path
    if results is not None:
        lines = ["### Checkpoints", "", "| row | methods | status | checkpoint | note |", "|---|---|---|---|---|"]
        for key, res in results.items():
            methods = ", ".join(dict.fromkeys(f"{r.method} ({t.label})" for t in tables for r in t.rows if r.key == key))
            lines.append(f"| {key} | {methods} | {res.status} | `{res.path}` | {res.note} |")
        parts.append("\n".join(lines))
    written["tables.md"] = out / "tables.md"
    written["tables.md"].write_text("\n\n".join(parts) + "\n")
    return written


_MARKED = re.compile(r"<!-- paper_tables:([A-Za-z0-9_]+) -->\n(.*?)<!-- /paper_tables:([A-Za-z0-9_]+) -->", re.S)
_OPENING = re.compile(r"<!-- paper_tables:([A-Za-z0-9_]+) -->")


def fill_markers(text: str, tables: Mapping[str, str]) -> tuple[str, list[str]]:
    """Put each table of ``tables`` ({name: markdown}) between its markers in ``text``:
    ``<!-- paper_tables:<name> -->``, a newline, ..., ``<!-- /paper_tables:<name> -->``. The table
    goes in without its ``###`` heading (the file has its own); markers of tables not in ``tables``
    keep what they hold.

    Returns:
        the new text and the names filled, in the order they appear.

    Raises:
        ValueError: a marker that names no table of :data:`TABLES`, an opening marker without its
            closing one (or closed by another table's), or a table marked twice (names it).
    """
    opened = _OPENING.findall(text)
    unknown = [n for n in opened if n not in TABLES]
    if unknown:
        raise ValueError(f"marker <!-- paper_tables:{unknown[0]} --> names no table; valid: {list(TABLES)}")
    check_unique("marked tables", opened)
    blocks = list(_MARKED.finditer(text))
    closed = [m.group(1) for m in blocks if m.group(1) == m.group(3)]
    if len(closed) != len(opened) or len(blocks) != len(opened):
        missing = next(n for n in opened if n not in closed)
        raise ValueError(f"marker <!-- paper_tables:{missing} --> has no closing <!-- /paper_tables:{missing} --> "
                         "after it (on a line of its own)")
    filled: list[str] = []

    def body(m: re.Match) -> str:
        name = m.group(1)
        if name not in tables:
            return m.group(0)
        filled.append(name)
        md = tables[name].strip("\n").split("\n")
        if md and md[0].startswith("### "):
            md = md[1:]
        return f"<!-- paper_tables:{name} -->\n" + "\n".join(md).strip("\n") + f"\n<!-- /paper_tables:{name} -->"

    return _MARKED.sub(body, text), filled


def into_files(paths: Sequence[Path], tables: Mapping[str, str], check_only: bool = False) -> None:
    """:func:`fill_markers` on each file of ``paths``, rewritten in place (``check_only``: read and
    checked, not written). ValueError naming the file when it is missing or its markers are wrong."""
    for path in paths:
        if not path.is_file():
            raise ValueError(f"--into {str(path)!r} is not a file")
        try:
            text, filled = fill_markers(path.read_text(), tables)
        except ValueError as err:
            raise ValueError(f"{path}: {err}") from None
        if check_only:
            continue
        path.write_text(text)
        print(f"{path}: wrote {', '.join(filled) or 'no table (no markers for these tables)'}")
