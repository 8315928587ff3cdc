"""The paper's comparison tables as data: the six metrics in the paper's order (:data:`METRICS`)
and every table of ``lego-h-paper.tex`` that compares methods (:data:`TABLES`), each method a
:class:`PaperRow` with the figures the paper prints and the row of ours
(:data:`legoh_rl.paper_tables.rows.ROWS`) it is compared with."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from legoh_rl.envs.metrics import METRIC_NAMES

__all__ = ["METRICS", "Value", "PaperRow", "PaperTable", "TABLES", "check_unique", "table_names"]

#: metric -> (column header, higher is better), in the paper's order (its tables' rows): SR, TC, TR
#: ("goal completeness", up), MEV, TTF ("safeness": MEV down, TTF up), T2R ("efficiency", down)
METRICS: dict[str, tuple[str, bool]] = {
    "success": ("SR (%) ↑", True),
    "trail_completion": ("TC (%) ↑", True),
    "traverse_rate": ("TR (%) ↑", True),
    "mev": ("MEV (%) ↓", False),
    "ttf": ("TTF (s) ↑", True),
    "time_to_reach": ("T2R (s) ↓", False),
}
assert tuple(METRICS) == METRIC_NAMES  # the evaluation's metrics, in the same order

Value = tuple[float, float]  # (mean, std)


@dataclass(frozen=True)
class PaperRow:
    """One method of a paper table.

    Attributes:
        method: the paper's name for it.
        key: its row in :data:`~legoh_rl.paper_tables.rows.ROWS`.
        paper: metric -> (mean, std) as printed (None: the table has no such figure); None for a
            row of ours only (not in the paper).
        group: which of our aggregate's rows it compares with: ``"overall"`` or a category.
    """

    method: str
    key: str
    paper: dict[str, Value | None] | None
    group: str = "overall"


@dataclass(frozen=True)
class PaperTable:
    """A comparison table of the paper.

    Attributes:
        name: its name on the command line; label: its ``\\label`` in the tex.
        caption: what it shows; note: how it differs from our protocol or layout (or "").
        rows: its methods, in the paper's order.
        contrasts: the paper's questions as pairs of its rows, ``(what, row a, row b)`` with the
            rows' keys: the table reports a - b in success rate, ours (with Welch's t and Cohen's
            d over the training seeds) beside the paper's.
    """

    name: str
    label: str
    caption: str
    rows: tuple[PaperRow, ...]
    note: str = ""
    contrasts: tuple[tuple[str, str, str], ...] = ()


def _p(*cells: str | None) -> dict[str, Value | None]:
    """The six figures of one paper column, in :data:`METRICS` order, each ``"mean±std"`` as in the
    tex (``$71.20\\pm0.72$``), or None where the table has none."""
    assert len(cells) == len(METRICS), cells
    out = {}
    for m, cell in zip(METRICS, cells, strict=True):
        if cell is None:
            out[m] = None
        else:
            mean, std = cell.split("±")
            out[m] = (float(mean), float(std))
    return out


# transcribed from /work/shared/reference/lego-h-paper.tex; each column in SR, TC, TR, MEV, TTF, T2R order
_LEGO_H_H1 = _p("68.40±1.34", "52.78±1.30", "71.96±2.37", "7.84±0.92", "7.46±0.17", "4.95±0.12")
_ORACLE_H1 = _p("71.20±0.72", "77.73±0.92", "73.60±0.81", "7.12±0.92", "7.25±0.09", "4.59±0.08")
_NO_HLM_H1 = _p("64.73±2.22", "52.50±1.52", "72.04±0.98", "10.40±1.50", "7.00±0.20", "5.13±0.12")
_VANILLA_H1 = _p("42.97±0.67", "32.01±0.61", "60.26±0.94", "9.41±1.27", "5.36±0.10", "6.50±0.07")
_EP_H = _p("28.80±0.88", "25.98±0.22", "64.16±0.48", "12.44±1.32", "4.64±0.13", "9.79±0.16")

_LONGER = ("LEGO-H, trained longer, is the same method as LEGO-H with more env steps of training (the env "
           "steps column): ours alone, with the paper's LEGO-H figures repeated under it.")

_CONVERGED = ("Ours only beyond the paper's Table 1: the same methods with each student trained until its "
              "curve flattens (the env steps column), all distilled from oracle_h1_real_pits.pt (the stage-5 oracle, "
              "the Oracle row's predecessor). LEGO-H and w TC-ViT "
              "share their DAgger phase (student_h1_real_pits' to 5.38M env steps, whose LEGO-H end is "
              "student_h1_real_pits.pt, training seed 0) and differ from there on by L_hie alone; Vanilla is the whole "
              "schedule with a ConvGRU. The paper's Table 1 figures are repeated under ours.")

TABLES: dict[str, PaperTable] = {t.name: t for t in (
    # \label{tab:ablation_h1}: "Ablation of LEGO-H's main components on H1."
    PaperTable("ablation", "tab:ablation_h1", "Ablation of LEGO-H's main components on H1", (
        PaperRow("Oracle", "h1_oracle", _ORACLE_H1),
        PaperRow("LEGO-H", "h1_lego_h", _LEGO_H_H1),
        PaperRow("w TC-ViT (no HLM)", "h1_no_hlm", _NO_HLM_H1),
        PaperRow("Vanilla (ConvGRU)", "h1_vanilla", _VANILLA_H1),
    ), contrasts=(("HLM", "h1_lego_h", "h1_no_hlm"), ("TC-ViT over a ConvGRU", "h1_no_hlm", "h1_vanilla"))),
    # the same table again with every student trained until its curve flattens (issue 48, goal 3)
    PaperTable("ablation_converged", "tab:ablation_h1",
               "Ablation of LEGO-H's main components on H1, the students trained to convergence", (
                   PaperRow("Oracle", "h1_oracle", _ORACLE_H1),
                   PaperRow("LEGO-H", "h1_lego_h_converged", _LEGO_H_H1),
                   PaperRow("w TC-ViT (no HLM)", "h1_no_hlm_converged", _NO_HLM_H1),
                   PaperRow("Vanilla (ConvGRU)", "h1_vanilla_converged", _VANILLA_H1),
               ), note=_CONVERGED,
               contrasts=(("HLM", "h1_lego_h_converged", "h1_no_hlm_converged"),
                          ("TC-ViT over a ConvGRU", "h1_no_hlm_converged", "h1_vanilla_converged"))),
    # \label{tab:hiking_benchmark}: "Humanoid hiking benchmark for H1 across all trail categories."
    PaperTable("benchmark", "tab:hiking_benchmark", "Humanoid hiking benchmark for H1 across all trail categories", (
        PaperRow("LEGO-H", "h1_lego_h", _LEGO_H_H1),
        PaperRow("LEGO-H, trained longer", "h1_lego_h_long", _LEGO_H_H1),
        PaperRow("EP-H", "h1_eph", _EP_H),
        PaperRow("RMA-H", "h1_rmah",
                 _p("65.17±2.05", "52.51±1.41", "74.61±0.93", "8.70±1.55", "6.97±0.17", "4.98±0.11")),
        PaperRow("RMA-B", "h1_rmab",
                 _p("48.11±0.72", "41.92±0.34", "69.85±1.50", "10.74±1.13", "5.22±0.03", "6.19±0.05")),
    ), note=_LONGER),
    # \label{tab:ablation_gru}: "GRU vs CTs at the end of TC-ViT." (SR and TTF only)
    PaperTable("gru_ct", "tab:ablation_gru", "GRU vs causal transformers (CTs) at the end of TC-ViT", (
        PaperRow("w GRU (LEGO-H)", "h1_lego_h", _p("68.40±1.34", None, None, None, "7.46±0.17", None)),
        PaperRow("w CTs", "h1_ct", _p("27.85±1.02", None, None, None, "5.44±0.34", None)),
    ), note="The paper reports SR and TTF only in this table (— for the others)."),
    # \label{tab:vae}: "Ablation of HLM." (full HLM vs a vanilla VAE prior)
    PaperTable("hlm_vae", "tab:vae", "Ablation of HLM: full HLM vs a vanilla VAE", (
        PaperRow("full HLM (LEGO-H)", "h1_lego_h", _LEGO_H_H1),
        PaperRow("Vanilla VAE", "h1_vanilla_vae",
                 _p("53.49±1.61", "43.00±0.96", "64.52±1.02", "9.26±1.08", "6.30±0.15", "6.02±0.05")),
    )),
    # \label{plug} (the table also carries a second, duplicate \label{tab:ablation_h1}):
    # "HLM as a plug-in supervision for other framework."
    PaperTable("hlm_plugin", "plug", "HLM as a plug-in supervision for EP-H", (
        PaperRow("EP-H", "h1_eph", _EP_H),
        PaperRow("EP-H + HLM", "h1_eph_hlm",
                 _p("35.53±1.30", "30.36±0.89", "58.23±0.76", "10.98±1.40", "5.04±0.16", "7.80±0.37")),
    )),
    # \label{tab:g1}: "LEGO-H on Humanoid G1 robot." (H1 as a reference)
    PaperTable("g1", "tab:g1", "LEGO-H on the G1 humanoid (H1 as a reference)", (
        PaperRow("H1 (LEGO-H)", "h1_lego_h", _LEGO_H_H1),
        PaperRow("H1 (LEGO-H, trained longer)", "h1_lego_h_long", _LEGO_H_H1),
        PaperRow("G1 (LEGO-H)", "g1_lego_h",
                 _p("63.96±1.03", "38.94±0.63", "62.21±0.97", "5.33±0.68", "7.24±0.22", "8.10±0.08")),
        PaperRow("G1 oracle (ours only)", "g1_oracle", None),
    ), note="The G1 oracle is not in the paper; it is listed as the teacher of a G1 student. " + _LONGER
         + " The env steps column counts the steps behind a warm start too: a student started from another's "
           "weights (`checkpoint.init`) has had their training as well."),
    # \label{tab:hiking_benchmark_terrains}: "EP-H vs RMA-B on each trail category."
    PaperTable("terrains", "tab:hiking_benchmark_terrains", "EP-H vs RMA-B on each trail category", (
        PaperRow("EP-H", "h1_eph", _p("16.98±0.85", "2.67±0.14", "70.88±1.41", "11.32±1.83", "3.33±0.13", "9.73±0.19"),
                 "randommix"),
        PaperRow("RMA-B", "h1_rmab", _p("30.99±0.95", "3.60±0.37", "76.74±1.13", "10.95±1.70", "4.14±0.20", "6.79±0.09"),
                 "randommix"),
        PaperRow("EP-H", "h1_eph", _p("16.12±0.66", "17.90±0.62", "55.75±0.58", "22.75±1.63", "3.50±0.08", "11.88±0.33"),
                 "ditch"),
        PaperRow("RMA-B", "h1_rmab", _p("32.80±1.56", "30.77±0.59", "63.49±1.42", "23.66±1.63", "4.56±0.18", "6.37±0.37"),
                 "ditch"),
        PaperRow("EP-H", "h1_eph", _p("46.54±2.64", "57.04±1.25", "68.95±1.79", "8.77±0.46", "6.44±0.21", "5.94±0.14"),
                 "hurdle"),
        PaperRow("RMA-B", "h1_rmab", _p("83.04±0.27", "76.72±0.47", "83.04±1.17", "12.90±1.92", "9.24±0.28", "4.22±0.04"),
                 "hurdle"),
        PaperRow("EP-H", "h1_eph", _p("18.13±1.19", "32.26±0.48", "58.74±1.21", "31.84±2.00", "4.36±0.20", "12.15±0.34"),
                 "gap"),
        PaperRow("RMA-B", "h1_rmab", _p("39.93±1.55", "44.27±1.06", "65.30±1.32", "24.10±2.09", "5.44±0.24", "7.99±0.17"),
                 "gap"),
        PaperRow("EP-H", "h1_eph", _p("63.29±1.50", "1.04±0.16", "82.61±1.18", "6.18±1.57", "8.96±0.49", "13.65±0.08"),
                 "forest"),
        PaperRow("RMA-B", "h1_rmab", _p("64.81±2.43", "1.86±0.38", "81.59±3.20", "5.69±1.04", "10.18±0.89", "13.20±0.24"),
                 "forest"),
    ), note="The paper's protocol here: 256 robots per trail category over its 25 scenes, 5 runs; ours: "
            "the rows of each category in our evaluation."),
)}


def check_unique(name: str, values: Sequence) -> None:
    """Refuse an empty or repeating list of ``values`` (ValueError naming ``name`` and the repeats)."""
    values = list(values)
    if not values:
        raise ValueError(f"{name} must name at least one value")
    dup = sorted({v for v in values if values.count(v) > 1}, key=str)
    if dup:
        raise ValueError(f"{name} must be distinct, got {values} (repeated: {dup})")


def table_names(names: Sequence[str]) -> list[str]:
    """The tables asked for, checked: known names, no repeats (ValueError naming the bad one)."""
    bad = [n for n in names if n not in TABLES]
    if bad:
        raise ValueError(f"unknown table {bad[0]!r}; valid: {list(TABLES)}")
    check_unique("tables", names)
    return list(names)
