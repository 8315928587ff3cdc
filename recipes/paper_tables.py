"""The paper's comparison tables, reproduced from whatever checkpoints are present.

    python recipes/paper_tables.py --trail-seeds 9101 9102 9103
    python recipes/paper_tables.py --trail-seeds 9101 9102 9103 --robots-per-cell 8 --variants 8
    python recipes/paper_tables.py --trail-seeds 9101 9102 --tables ablation g1 --out outputs/tables_h1
    python recipes/paper_tables.py --trail-seeds 9101 --categories randommix --levels 0 --tables ablation
    python recipes/paper_tables.py --trail-seeds 9101 9102 9103 --protocol paper   # 20 robots per cell, 5 runs
    python recipes/paper_tables.py --trail-seeds 9101 9102 9103 --domain-rand --out outputs/tables_dr  # robustness
    python recipes/paper_tables.py --only-paper                                    # the paper's numbers alone

Every table of ``lego-h-paper.tex`` that compares methods (:data:`TABLES`: the ablation on H1, the
H1 benchmark, GRU vs causal transformers, HLM vs a vanilla VAE, HLM as a plug-in for EP-H, G1 vs
H1, and EP-H vs RMA-B per trail category) is written under ``--out`` as ``<table>.md`` and
``<table>.csv``, with ``tables.md`` holding them all, the command line and the trail seeds. Each
method of a table is a row of ours (``mean ± std`` of the six metrics) with the paper's row under
it.

Each method is one or more checkpoints under ``--checkpoints`` (:data:`ROWS`: ``oracle_h1.pt``,
``student_h1.pt``, ``student_g1.pt``, ``ablations/<robot>_<row>.pt``; every row under
``ablations/`` also takes training seeds, ``ablations/<robot>_<row>_seed<k>.pt``, as the runs of
``recipes/config/experiment/<robot>_<row>.yaml`` with ``env.seed=<k>`` are named). A student's
file is checked against the row before it is
used (robot, perception, HLM on or off, vanilla VAE; see :func:`checkpoint_info` and
:func:`mismatch`): ``student_h1.pt`` is a LEGO-H seed when it was trained with HLM and a "w TC-ViT"
seed when it was not. A row with several matching files is reported as the mean ± std over them
(:func:`across_seeds`: each seed's mean over the trail grids, then over seeds), so a difference
between rows can be read against the spread between training seeds. A row with no matching file
is listed as *not trained* with the path that would hold it.

Every checkpoint is evaluated once, by ``recipes/evaluate.py``'s ``evaluate`` (its artefacts
under ``<out>/evals/<checkpoint>/``), on the same protocol: the categories x levels cells with
``--robots-per-cell`` robots each on ``--variants`` trail variants, repeated on the trail grid of
each of ``--trail-seeds``; for one checkpoint mean ± std is over the trail grids (and runs), as in
``evaluate.py``. An evaluation already in ``--out`` for the same checkpoint file and protocol is
read back rather than run again (``--fresh`` runs everything), so the command can be repeated as
rows are trained; ``--reuse-from DIR`` also takes up ``evaluate.py`` runs made on their own
(``DIR`` an output folder of one, or a folder of them) whose ``evaluated_with.json`` matches.
``--archive DIR`` looks evaluations up in ``DIR`` too and keeps each one there, its record and
``table.csv`` only (:func:`archive_evaluation`): ``docs/paper_tables/evals`` is committed, so a
fresh checkout rewrites the tables of RESULTS.md without evaluating the checkpoints again.
The paper's protocol (512 robots, 5 runs) is larger; the comparison is of the same metrics, not
of the same sample.

``--into FILE`` also writes each table into a markdown file that asks for it, between the markers
``<!-- paper_tables:<table> -->`` and ``<!-- /paper_tables:<table> -->`` (:func:`fill_markers`;
RESULTS.md holds its tables so), keeping everything else in the file as it is.
"""

from __future__ import annotations

import argparse
import csv
import functools
import hashlib
import json
import math
import re
import shlex
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import evaluate as evaluate_recipe
import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from legoh_rl.envs.metrics import METRIC_NAMES
from legoh_rl.envs.trails import CATEGORIES, NUM_LEVELS

CONFIG_DIR = Path(__file__).resolve().parent / "config"

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


# ---------------------------------------------------------------------------------------------
# Which checkpoint holds which method


@dataclass(frozen=True)
class RowSpec:
    """A method of the paper and the checkpoint that holds ours.

    Attributes:
        key: our name for it (``h1_lego_h``, ``h1_no_hlm``, ...).
        robot: ``"h1"`` or ``"g1"``.
        kind: ``"oracle"`` or ``"student"`` (the checkpoint's ``meta["kind"]``).
        perception: the student's ``meta["perception"]`` (``recipes/unified.py``'s
            ``student.perception``); None for an oracle.
        hlm: whether the student was trained with HLM (``hlm.enabled``); None: either.
        vanilla_vae: whether its HLM prior is the vanilla VAE (``hlm.vanilla_vae``); None: either.
        locomotion: the student's locomotion module (``student.locomotion``): ``learned`` or
            ``oracle`` (the teacher's actor, frozen: the paper's RMA baselines); None: either.
        paths: candidate files relative to the checkpoints folder, globs allowed
            (``ablations/h1_no_hlm_seed*.pt``); every existing file that matches is one training
            seed of the row, and the first candidate names where the row would go.
    """

    key: str
    robot: str
    kind: str
    paths: tuple[str, ...]
    perception: str | None = None
    hlm: bool | None = None
    vanilla_vae: bool | None = None
    locomotion: str | None = None


def _student(key: str, perception: str, hlm: bool | None = None, vanilla_vae: bool | None = None,
             paths: tuple[str, ...] | None = None, locomotion: str | None = "learned") -> RowSpec:
    robot = key.split("_", 1)[0]
    return RowSpec(key, robot, "student", paths or (f"ablations/{key}.pt", f"ablations/{key}_seed*.pt"),
                   perception, hlm, vanilla_vae, locomotion)


#: every method of the tables, by key. LEGO-H is TC-ViT with HLM (masked VAE); "w TC-ViT" is
#: TC-ViT without HLM, held by ``ablations/h1_no_hlm.pt`` or else by ``student_h1.pt`` when that
#: student was trained without HLM. The paper does not say whether Vanilla (ConvGRU), w CTs and
#: the RMA baselines used HLM, so those rows accept either; EP-H and EP-H + HLM differ by it.
ROWS: dict[str, RowSpec] = {spec.key: spec for spec in (
    RowSpec("h1_oracle", "h1", "oracle", ("oracle_h1.pt",)),
    _student("h1_lego_h", "tcvit", hlm=True, vanilla_vae=False,
             paths=("student_h1.pt", "ablations/h1_lego_h_seed*.pt")),
    _student("h1_no_hlm", "tcvit", hlm=False,
             paths=("ablations/h1_no_hlm.pt", "ablations/h1_no_hlm_seed*.pt", "student_h1.pt")),
    _student("h1_vanilla", "vanilla"),
    _student("h1_eph", "eph", hlm=False),
    _student("h1_rmah", "rmah", locomotion="oracle"),  # RMA: "a frozen oracle policy with an adapter"
    _student("h1_rmab", "rmab", locomotion="oracle"),
    _student("h1_ct", "tcvit_ct"),
    _student("h1_vanilla_vae", "tcvit", hlm=True, vanilla_vae=True),
    _student("h1_eph_hlm", "eph", hlm=True, vanilla_vae=False),
    _student("g1_lego_h", "tcvit", hlm=True, vanilla_vae=False, paths=("student_g1.pt",)),
    RowSpec("g1_oracle", "g1", "oracle", ("oracle_g1_trails.pt",)),  # the G1 student's teacher
)}


@dataclass(frozen=True)
class CheckpointInfo:
    """What a checkpoint is, as far as the tables care (None: not recorded).

    Attributes:
        robot, kind, perception: ``meta["robot"]``, ``meta["kind"]``, ``meta["perception"]``.
        hlm: trained with HLM; vanilla_vae: HLM's prior was the vanilla VAE (False without HLM).
        locomotion: ``meta["locomotion"]``, ``"learned"`` when absent (a student's own MLP).
    """

    robot: str | None
    kind: str | None
    perception: str | None = None
    hlm: bool | None = None
    vanilla_vae: bool | None = None
    locomotion: str | None = None


def checkpoint_info(meta: Mapping, config: Mapping | None = None, iteration: int | None = None) -> CheckpointInfo:
    """Read a checkpoint's ``meta`` block (and its training ``config``, for HLM).

    ``recipes/unified.py`` records the robot, kind, perception and preset in ``meta`` but not
    whether HLM was on; its checkpoints (slim exports too) carry the training config, whose
    ``hlm.enabled``, ``hlm.warmup_iters`` and ``hlm.vanilla_vae`` say it. Rule: ``meta["hlm"]``
    (bool) and ``meta["vanilla_vae"]`` when present, else ``config["hlm"]["enabled"]`` and
    ``config["hlm"]["vanilla_vae"]`` (False when absent), where an enabled HLM whose
    ``warmup_iters`` the checkpoint's ``iteration`` has not reached counts as off (its L_hie never
    trained the student: only the masked VAE did); with neither, HLM is unknown (None) and no row
    that needs HLM on or off takes the checkpoint.

    Args:
        meta: the checkpoint's ``meta`` dict.
        config: the checkpoint's ``config`` dict (or None).
        iteration: the checkpoint's training iteration (or None: warm-up not checked).

    Returns:
        the :class:`CheckpointInfo`.
    """
    hlm, vae = meta.get("hlm"), meta.get("vanilla_vae")
    if hlm is None:
        section = (config or {}).get("hlm") or {}
        hlm = section.get("enabled")
        warmup = section.get("warmup_iters")
        if hlm and warmup is not None and iteration is not None and int(iteration) < int(warmup):
            hlm = False  # L_hie had not joined yet
        if vae is None:
            vae = section.get("vanilla_vae")
    hlm = None if hlm is None else bool(hlm)
    vae = None if hlm is None else (bool(hlm) and bool(vae))  # the VAE prior matters only with HLM
    kind = meta.get("kind")
    return CheckpointInfo(robot=meta.get("robot"), kind=kind,
                          perception=meta.get("perception") if kind == "student" else None,
                          hlm=hlm if kind == "student" else None, vanilla_vae=vae if kind == "student" else None,
                          locomotion=meta.get("locomotion", "learned") if kind == "student" else None)


def describe(info: CheckpointInfo) -> str:
    """A short description, e.g. ``"H1 student (tcvit, HLM on)"``."""
    robot = (info.robot or "?").upper()
    if info.kind != "student":
        return f"{robot} {info.kind or 'unknown kind'}"
    hlm = {None: "HLM unknown", False: "HLM off", True: "HLM on"}[info.hlm]
    if info.vanilla_vae:
        hlm += ", vanilla VAE"
    if info.locomotion == "oracle":
        hlm += ", frozen oracle locomotion"
    return f"{robot} student ({info.perception}, {hlm})"


def mismatch(spec: RowSpec, info: CheckpointInfo) -> str | None:
    """Why a checkpoint cannot be ``spec``'s row (None: it can).

    Returns:
        None, or a sentence naming the first differing field, e.g. ``"HLM off, the row needs HLM
        on"``.
    """
    if info.robot != spec.robot:
        return f"robot {info.robot!r}, the row needs {spec.robot!r}"
    if info.kind != spec.kind:
        return f"kind {info.kind!r}, the row needs {spec.kind!r}"
    if spec.kind != "student":
        return None
    if info.perception != spec.perception:
        return f"perception {info.perception!r}, the row needs {spec.perception!r}"
    if spec.hlm is not None:
        if info.hlm is None:
            return "HLM on or off is not recorded (no meta['hlm'], no config.hlm.enabled)"
        if info.hlm != spec.hlm:
            return f"HLM {'on' if info.hlm else 'off'}, the row needs HLM {'on' if spec.hlm else 'off'}"
    if spec.vanilla_vae is not None and info.hlm and info.vanilla_vae != spec.vanilla_vae:
        return f"{'a' if info.vanilla_vae else 'no'} vanilla VAE, the row needs {'one' if spec.vanilla_vae else 'the masked VAE'}"
    if spec.locomotion is not None and info.locomotion != spec.locomotion:
        return f"{info.locomotion} locomotion, the row needs {spec.locomotion} (student.locomotion={spec.locomotion})"
    return None


def read_info(path: Path) -> CheckpointInfo:
    """:func:`checkpoint_info` of the checkpoint at ``path`` (loaded to the CPU)."""
    from legoh_rl.training.checkpoint import load_checkpoint

    state = load_checkpoint(path)
    return checkpoint_info(state["meta"], state.get("config"), state.get("iteration"))


@dataclass(frozen=True)
class Resolution:
    """Where a row's checkpoints are.

    Attributes:
        key: the row (a key of :data:`ROWS`).
        path: the first matching checkpoint, or the path that would hold the row.
        found: whether the row has a checkpoint.
        note: what the other candidate files hold, when some exist but do not match.
        paths: every matching checkpoint, one per training seed (empty when not found).
    """

    key: str
    path: Path
    found: bool
    note: str = ""
    paths: tuple[Path, ...] = ()


def resolve_row(spec: RowSpec, root: Path, read: Callable[[Path], CheckpointInfo] = read_info) -> Resolution:
    """The checkpoints of ``spec`` under ``root``: every candidate file that exists and matches
    (globs expanded in name order), each a training seed of the row.

    Args:
        spec: the row.
        root: the checkpoints folder.
        read: path -> :class:`CheckpointInfo` (tests pass their own).

    Returns:
        the :class:`Resolution`; when no candidate matches, ``path`` is the first candidate and
        ``note`` says what each existing candidate holds instead.
    """
    notes, found = [], []
    for rel in spec.paths:
        for path in (sorted(root.glob(rel)) if any(c in rel for c in "*?[") else [root / rel]):
            if not path.is_file() or path in found:
                continue
            info = read(path)
            why = mismatch(spec, info)
            if why is None:
                found.append(path)
            else:
                notes.append(f"{path} holds the {describe(info)}: {why}")
    if found:
        return Resolution(spec.key, found[0], True, "; ".join(notes), paths=tuple(found))
    return Resolution(spec.key, root / spec.paths[0], False, "; ".join(notes))


def across_seeds(aggregates: Sequence[Mapping[str, Mapping[str, Value]]]) -> dict[str, dict[str, Value]]:
    """One row's figures from several training seeds: per group and metric, the mean and std
    (population, as ``evaluate.py``'s over trail grids) of the seeds' means; NaN means are left
    out, and a metric no seed has is (nan, nan).

    Args:
        aggregates: each seed's ``{group: {metric: (mean, std)}}``; only groups every seed has.
    """
    groups = set.intersection(*(set(a) for a in aggregates))
    out: dict[str, dict[str, Value]] = {}
    for group in sorted(groups, key=lambda g: (g == "overall", g)):
        metrics = dict.fromkeys(k for a in aggregates for k in a[group])
        out[group] = {}
        for metric in metrics:
            means = [a[group][metric][0] for a in aggregates if metric in a[group]]
            finite = [m for m in means if not math.isnan(m)]
            out[group][metric] = ((float(np.mean(finite)), float(np.std(finite))) if finite
                                  else (math.nan, math.nan))
    return out


# ---------------------------------------------------------------------------------------------
# The paper's numbers


@dataclass(frozen=True)
class PaperRow:
    """One method of a paper table.

    Attributes:
        method: the paper's name for it.
        key: its row in :data:`ROWS`.
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
    """

    name: str
    label: str
    caption: str
    rows: tuple[PaperRow, ...]
    note: str = ""


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
_EP_H = _p("28.80±0.88", "25.98±0.22", "64.16±0.48", "12.44±1.32", "4.64±0.13", "9.79±0.16")

TABLES: dict[str, PaperTable] = {t.name: t for t in (
    # \label{tab:ablation_h1}: "Ablation of LEGO-H's main components on H1."
    PaperTable("ablation", "tab:ablation_h1", "Ablation of LEGO-H's main components on H1", (
        PaperRow("Oracle", "h1_oracle",
                 _p("71.20±0.72", "77.73±0.92", "73.60±0.81", "7.12±0.92", "7.25±0.09", "4.59±0.08")),
        PaperRow("LEGO-H", "h1_lego_h", _LEGO_H_H1),
        PaperRow("w TC-ViT (no HLM)", "h1_no_hlm",
                 _p("64.73±2.22", "52.50±1.52", "72.04±0.98", "10.40±1.50", "7.00±0.20", "5.13±0.12")),
        PaperRow("Vanilla (ConvGRU)", "h1_vanilla",
                 _p("42.97±0.67", "32.01±0.61", "60.26±0.94", "9.41±1.27", "5.36±0.10", "6.50±0.07")),
    )),
    # \label{tab:hiking_benchmark}: "Humanoid hiking benchmark for H1 across all trail categories."
    PaperTable("benchmark", "tab:hiking_benchmark", "Humanoid hiking benchmark for H1 across all trail categories", (
        PaperRow("LEGO-H", "h1_lego_h", _LEGO_H_H1),
        PaperRow("EP-H", "h1_eph", _EP_H),
        PaperRow("RMA-H", "h1_rmah",
                 _p("65.17±2.05", "52.51±1.41", "74.61±0.93", "8.70±1.55", "6.97±0.17", "4.98±0.11")),
        PaperRow("RMA-B", "h1_rmab",
                 _p("48.11±0.72", "41.92±0.34", "69.85±1.50", "10.74±1.13", "5.22±0.03", "6.19±0.05")),
    )),
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
        PaperRow("G1 (LEGO-H)", "g1_lego_h",
                 _p("63.96±1.03", "38.94±0.63", "62.21±0.97", "5.33±0.68", "7.24±0.22", "8.10±0.08")),
        PaperRow("G1 oracle (ours only)", "g1_oracle", None),
    ), note="The G1 oracle is not in the paper; it is listed as the teacher of a G1 student."),
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


# ---------------------------------------------------------------------------------------------
# Evaluation


@dataclass(frozen=True)
class Settings:
    """The protocol every checkpoint is evaluated on (``recipes/evaluate.py``'s config keys).

    Attributes:
        trail_seeds: one trail grid per seed (distinct, at least one); mean ± std is over them.
        robots_per_cell, runs: per (category, level) cell and per trail grid (``protocol="cpu"``;
            ``"paper"`` sets 20 and 5).
        variants: trail variants per cell; categories, levels: the cells.
        protocol: ``"cpu"`` or ``"paper"``.
        device, num_threads: where the policy runs, physics threads (None: the default).
        video: render ``evaluate.py``'s video of each checkpoint; logger: ``"csv"`` or ``"wandb"``.
        domain_rand: evaluate under the training's randomisation (``evaluate.py domain_rand=true``)
            instead of on the nominal robot.
    """

    trail_seeds: tuple[int, ...]
    robots_per_cell: int = 2
    runs: int = 1
    variants: int = 2
    categories: tuple[str, ...] = CATEGORIES
    levels: tuple[int, ...] = tuple(range(NUM_LEVELS))
    protocol: str = "cpu"
    device: str = "auto"
    num_threads: int | None = None
    video: bool = False
    logger: str = "csv"
    domain_rand: bool = False

    def __post_init__(self) -> None:
        """Refuse a bad protocol before any evaluation, with ``evaluate.py``'s own checks (its
        protocol and trail seeds, :class:`~legoh_rl.training.evaluation.EvalProtocol`'s cells)."""
        keys = ("protocol", "categories", "levels", "robots_per_cell", "runs", "trail_seeds")
        cfg = OmegaConf.create({**{k: v for k, v in self.overrides(Path("-"), Path("-")).items() if k in keys},
                                "seed": 0})
        evaluate_recipe.protocol_of(cfg)
        evaluate_recipe.trail_seeds_of(cfg)
        if int(self.variants) < 1:
            raise ValueError(f"variants must be >= 1, got {self.variants}")
        if self.num_threads is not None and self.num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {self.num_threads}")
        if self.logger not in ("csv", "wandb"):
            raise ValueError(f"unknown logger {self.logger!r}; valid: ['csv', 'wandb']")

    def overrides(self, checkpoint: Path, output_dir: Path) -> dict:
        """The ``evaluate.yaml`` keys for one checkpoint."""
        return {"checkpoint": str(checkpoint), "protocol": self.protocol, "robots_per_cell": self.robots_per_cell,
                "runs": self.runs, "variants": self.variants, "categories": list(self.categories),
                "levels": list(self.levels), "trail_seeds": list(self.trail_seeds), "device": self.device,
                "num_threads": self.num_threads, "output_dir": str(output_dir), "video": self.video,
                "domain_rand": self.domain_rand,
                # evaluated again only where no evaluation there matches: the earlier one moves into
                # overwritten-<time>/ (where find_evaluation still finds it), not mixed with the new
                "overwrite": True,
                "logger": {"backend": self.logger, "exp_name": f"paper_tables_{output_dir.name}"}}

    def describe(self) -> str:
        """One line: the cells, robots, runs and trail grids."""
        paper = self.protocol == "paper"
        robots = evaluate_recipe.PAPER_ROBOTS_PER_CELL if paper else self.robots_per_cell
        runs = evaluate_recipe.PAPER_RUNS if paper else self.runs
        episodes = robots * len(self.categories) * len(self.levels) * runs * len(self.trail_seeds)
        return (f"protocol {self.protocol}: {robots} robot(s) per cell on {self.variants} trail variant(s), "
                f"categories {list(self.categories)} x levels {list(self.levels)}, {runs} run(s) on each of "
                f"{len(self.trail_seeds)} trail grid(s) (seeds {list(self.trail_seeds)}): {episodes} episodes per "
                "checkpoint, one 30 s episode each"
                + (", under the training's domain randomisation" if self.domain_rand else ""))


def _check_unique(name: str, values: Sequence) -> None:
    values = list(values)
    if not values:
        raise ValueError(f"{name} must name at least one value")
    dup = sorted({v for v in values if values.count(v) > 1}, key=str)
    if dup:
        raise ValueError(f"{name} must be distinct, got {values} (repeated: {dup})")


RECORD_NAME = evaluate_recipe.RECORD_NAME


def find_evaluation(record: dict, folders: Sequence[Path]) -> Path | None:
    """A folder holding an evaluation made with ``record`` (its :data:`RECORD_NAME` equal to it,
    beside its ``table.csv``): each of ``folders`` or one of their subfolders; None if none."""
    for folder in folders:
        for stamp in [Path(folder) / RECORD_NAME, *sorted(Path(folder).glob(f"*/{RECORD_NAME}"))]:
            if stamp.is_file() and (stamp.parent / "table.csv").is_file() and json.loads(stamp.read_text()) == record:
                return stamp.parent
    return None


def read_table_csv(path: Path) -> dict[str, dict[str, Value]]:
    """An evaluation's ``table.csv`` (``category,metric,mean,std``) as its aggregate."""
    rows: dict[str, dict[str, Value]] = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            rows.setdefault(r["category"], {})[r["metric"]] = (float(r["mean"]), float(r["std"]))
    return rows


def archive_evaluation(found: Path, record: dict, archive: Path, name: str) -> Path:
    """Keep an evaluation's figures and what they depend on (its :data:`RECORD_NAME` and
    ``table.csv``, a few kB) in ``archive/<name>-<record digest>/``, a folder that can be committed
    so a fresh checkout refills the tables without evaluating again; returns that folder. The digest
    (12 hex digits of the record's SHA-256) keeps the same checkpoint's evaluations on other
    protocols apart."""
    digest = hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()[:12]
    kept = Path(archive) / f"{name}-{digest}"
    if kept.resolve() != Path(found).resolve():
        kept.mkdir(parents=True, exist_ok=True)
        (kept / "table.csv").write_bytes((Path(found) / "table.csv").read_bytes())
        (kept / RECORD_NAME).write_text(json.dumps(record, indent=1) + "\n")  # last: only a complete copy matches
    return kept


def evaluate_checkpoint(path: Path, settings: Settings, output_dir: Path, reuse: bool = True,
                        reuse_from: Sequence[Path] = (), archive: Path | None = None) -> dict[str, dict[str, Value]]:
    """``recipes/evaluate.py``'s ``evaluate`` on one checkpoint, its config composed from
    ``evaluate.yaml`` with ``settings``.

    Each evaluation leaves :data:`RECORD_NAME` beside its ``table.csv``
    (``evaluate.evaluation_record``); with ``reuse`` a folder whose record matches (the same
    checkpoint file and protocol), ``output_dir`` or one found in ``reuse_from`` (an
    ``evaluate.py`` run's output folder, or a folder of them), is read back instead of evaluated
    again, so the tables can be rewritten as rows are added without re-running the others
    (``--fresh``: evaluate everything). With ``archive`` the evaluation is also looked up there and
    kept there (:func:`archive_evaluation`).

    Returns:
        the aggregate: {group: {metric: (mean, std)}}, groups the categories and ``"overall"``.
    """
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
        cfg = compose(config_name="evaluate")
    cfg = OmegaConf.merge(cfg, settings.overrides(path, output_dir))
    record = evaluate_recipe.evaluation_record(cfg)
    stamp = output_dir / RECORD_NAME
    searched = [output_dir, *([archive] if archive is not None else []), *reuse_from]
    found = find_evaluation(record, searched) if reuse else None
    if found is not None:
        print(f"{path}: reusing the evaluation in {found} (same checkpoint and protocol)", flush=True)
        rows = read_table_csv(found / "table.csv")
    else:
        rows = evaluate_recipe.evaluate(cfg)["rows"]  # moves an earlier evaluation there aside, its record too
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(json.dumps(record, indent=1) + "\n")
        found = output_dir
    if archive is not None:
        archive_evaluation(found, record, archive, output_dir.name)
    return rows


@dataclass
class RowResult:
    """Our figures for one row.

    Attributes:
        key: the row; status: ``"evaluated"``, ``"not trained"`` or ``"failed"``.
        path: the checkpoint evaluated (the first, with several seeds), or the one that would
            hold the row.
        note: why not trained (what other candidates hold) or why the evaluation failed.
        rows: the aggregate ({group: {metric: (mean, std)}}) when evaluated: one checkpoint's
            mean ± std over trail grids, or with several seeds the mean ± std over the seeds
            (:func:`across_seeds`).
        paths: every checkpoint of the row (its training seeds).
        per_seed: each checkpoint's own aggregate, in the order of ``paths``.
    """

    key: str
    status: str
    path: Path
    note: str = ""
    rows: dict[str, dict[str, Value]] | None = field(default=None, repr=False)
    paths: tuple[Path, ...] = ()
    per_seed: list[dict] | None = field(default=None, repr=False)


def run_rows(keys: Sequence[str], root: Path, settings: Settings, out: Path,
             evaluate_fn: Callable[[Path, Settings, Path], dict] = evaluate_checkpoint,
             read: Callable[[Path], CheckpointInfo] = read_info) -> dict[str, RowResult]:
    """Resolve and evaluate rows, each checkpoint once.

    Args:
        keys: rows of :data:`ROWS`.
        root: the checkpoints folder.
        settings: the protocol.
        out: the output folder (each evaluation writes under ``out/evals/<checkpoint>``).
        evaluate_fn: (path, settings, output_dir) -> aggregate; ``read``: path -> info (for tests).

    Returns:
        {key: :class:`RowResult`}. An evaluation that raises is recorded as ``"failed"`` (the
        error in ``note``) and the other rows go on.
    """
    cache: dict[Path, tuple[str, object]] = {}
    results = {}
    for key in dict.fromkeys(keys):
        res = resolve_row(ROWS[key], root, read)
        if not res.found:
            results[key] = RowResult(key, "not trained", res.path, res.note)
            print(f"{key}: not trained ({res.path}{'; ' + res.note if res.note else ''})", flush=True)
            continue
        for path in res.paths:
            where = path.resolve()
            if where not in cache:
                print(f"\n=== {key}: evaluating {path} ===", flush=True)
                name = str(path.relative_to(root).with_suffix("")).replace("/", "_")
                try:
                    cache[where] = ("evaluated", evaluate_fn(path, settings, out / "evals" / name))
                except Exception as err:  # one bad checkpoint must not lose the others' hours of evaluation
                    cache[where] = ("failed", f"{type(err).__name__}: {err}")
                    print(f"{key}: evaluation of {path} failed: {cache[where][1]}", file=sys.stderr, flush=True)
        outcomes = [cache[p.resolve()] for p in res.paths]
        failed = [str(value) if len(res.paths) == 1 else f"{p}: {value}"
                  for p, (status, value) in zip(res.paths, outcomes, strict=True) if status == "failed"]
        if failed:  # a row is not reported on fewer seeds than it has
            results[key] = RowResult(key, "failed", res.path, note="; ".join(failed), paths=res.paths)
            continue
        per_seed = [value for _, value in outcomes]
        rows = per_seed[0] if len(per_seed) == 1 else across_seeds(per_seed)
        results[key] = RowResult(key, "evaluated", res.path, rows=rows, paths=res.paths, per_seed=per_seed)
    return results


# ---------------------------------------------------------------------------------------------
# Writing the tables


def fmt(value: Value | None) -> str:
    """``"mean ± std"`` with two decimals (as the paper), ``"n/a"`` for NaN, ``"—"`` for None."""
    if value is None:
        return "—"
    mean, std = value
    if math.isnan(mean):
        return "n/a"
    return f"{mean:.2f} ± {std:.2f}"


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


def markdown(table: PaperTable, results: Mapping[str, RowResult] | None) -> str:
    """One table as markdown: per method a row of ours and the paper's under it.

    Args:
        table: the table.
        results: {row key: :class:`RowResult`}, or None for the paper's rows alone.

    Returns:
        the markdown (a heading, the note if any, the table).
    """
    grouped = any(r.group != "overall" for r in table.rows)
    head = ["method"] + (["trails"] if grouped else []) + ["source"] + [METRICS[m][0] for m in METRICS]
    head += [] if results is None else ["checkpoint"]
    lines = [f"### {table.caption} (`{table.label}`)", ""]
    if table.note:
        lines += [table.note, ""]
    lines += ["| " + " | ".join(head) + " |",
              "|" + "|".join("---:" if h in [v[0] for v in METRICS.values()] else "---" for h in head) + "|"]
    for row in table.rows:
        trails = [row.group] if grouped else []
        if results is not None:
            status, ours, where = _ours(row, results.get(row.key))
            cells = [fmt(ours[m]) for m in METRICS] if status == "evaluated" else [status] + ["—"] * (len(METRICS) - 1)
            lines.append("| " + " | ".join([row.method, *trails, "ours", *cells, where]) + " |")
        if row.paper is not None:
            name = "" if results is not None else row.method
            lines.append("| " + " | ".join([name, *trails, "paper", *(fmt(row.paper[m]) for m in METRICS)]
                                           + ([""] if results is not None else [])) + " |")
    return "\n".join(lines)


def csv_rows(table: PaperTable, results: Mapping[str, RowResult] | None) -> list[dict]:
    """One table as CSV records: per method one ``ours`` record (unless ``results`` is None) and
    one ``paper`` record (when the paper has the row), each with ``<metric>_mean``/``_std``
    (empty when there is no figure) and ``status``/``checkpoint``/``note`` (a row's training
    seeds' checkpoints joined by ``;``)."""
    out = []
    for row in table.rows:
        base = {"table": table.name, "label": table.label, "method": row.method, "row": row.key, "trails": row.group}
        if results is not None:
            res = results.get(row.key)
            status, ours, _ = _ours(row, res)
            where = "" if res is None else ";".join(str(q) for q in (res.paths or (res.path,)))
            rec = {**base, "source": "ours", "status": status, "checkpoint": where,
                   "note": res.note if res else ""}
            out.append(_with_metrics(rec, ours))
        if row.paper is not None:
            out.append(_with_metrics({**base, "source": "paper", "status": "paper", "checkpoint": "", "note": ""},
                                     row.paper))
    return out


CSV_FIELDS = (["table", "label", "method", "row", "trails", "source", "status"]
              + [f"{m}_{s}" for m in METRICS for s in ("mean", "std")] + ["checkpoint", "note"])


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
    _check_unique("marked tables", opened)
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


# ---------------------------------------------------------------------------------------------
# Command line


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


def table_names(names: Sequence[str]) -> list[str]:
    """The tables asked for, checked: known names, no repeats (ValueError naming the bad one)."""
    bad = [n for n in names if n not in TABLES]
    if bad:
        raise ValueError(f"unknown table {bad[0]!r}; valid: {list(TABLES)}")
    _check_unique("tables", names)
    return list(names)


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
