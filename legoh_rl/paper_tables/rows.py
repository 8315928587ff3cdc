"""Which checkpoint holds which method: the rows of ours (:data:`ROWS`), what a checkpoint is as far
as the tables care (:func:`checkpoint_info`, from its meta block and training config), whether it
can be a row (:func:`mismatch`), every training seed of a row under a checkpoints folder
(:func:`resolve_row`) and a row's figures over its seeds (:func:`across_seeds`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from legoh_rl.paper_tables.paper import Value
from legoh_rl.training.checkpoint import load_checkpoint, warm_start_frames

__all__ = ["RowSpec", "ROWS", "CheckpointInfo", "checkpoint_info", "describe", "mismatch", "read_info",
           "Resolution", "resolve_row", "across_seeds"]


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
#: TC-ViT without HLM. The ablation rows (``ablations/<key>.pt``, ``ablations/<key>_seed*.pt``)
#: share one training budget, so that Table 1 compares methods, not budgets; ``student_h1.pt``,
#: the H1 student trained for longer, is a row of its own (``h1_lego_h_long``). The paper does
#: not say whether Vanilla (ConvGRU), w CTs and the RMA baselines used HLM, so those rows accept
#: either; EP-H and EP-H + HLM differ by it.
ROWS: dict[str, RowSpec] = {spec.key: spec for spec in (
    RowSpec("h1_oracle", "h1", "oracle", ("oracle_h1.pt",)),
    _student("h1_lego_h", "tcvit", hlm=True, vanilla_vae=False),
    _student("h1_lego_h_long", "tcvit", hlm=True, vanilla_vae=False, paths=("student_h1.pt",)),
    _student("h1_no_hlm", "tcvit", hlm=False),
    _student("h1_vanilla", "vanilla"),
    # Table 1 at convergence: seed 0 of LEGO-H is student_h1_real_pits.pt itself (its run is the
    # branch point of the others: experiment=h1_lego_h_converged / h1_no_hlm_converged /
    # h1_vanilla_converged)
    _student("h1_lego_h_converged", "tcvit", hlm=True, vanilla_vae=False,
             paths=("student_h1_real_pits.pt", "ablations/h1_lego_h_converged_seed*.pt")),
    _student("h1_no_hlm_converged", "tcvit", hlm=False, paths=("ablations/h1_no_hlm_converged_seed*.pt",)),
    _student("h1_vanilla_converged", "vanilla", paths=("ablations/h1_vanilla_converged_seed*.pt",)),
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
        frames: the env steps it was trained for (the checkpoint's ``frames``).
    """

    robot: str | None
    kind: str | None
    perception: str | None = None
    hlm: bool | None = None
    vanilla_vae: bool | None = None
    locomotion: str | None = None
    frames: int | None = None


def checkpoint_info(meta: Mapping, config: Mapping | None = None, iteration: int | None = None,
                    frames: int | None = None) -> CheckpointInfo:
    """Read a checkpoint's ``meta`` block (and its training ``config``, for HLM).

    ``recipes/unified.py`` records the robot, kind, perception and preset in ``meta`` but not
    whether HLM was on; its checkpoints (slim exports too) carry the training config, whose
    ``hlm.enabled``, ``hlm.warmup_iters`` and ``hlm.vanilla_vae`` say it. Rule: ``meta["hlm"]``
    (bool) and ``meta["vanilla_vae"]`` when present, else ``config["hlm"]["enabled"]`` and
    ``config["hlm"]["vanilla_vae"]`` (False when absent), where an enabled HLM whose
    ``warmup_iters`` the checkpoint's ``iteration`` (updates done) has not passed counts as off (its
    L_hie never trained the student: only the masked VAE did); with neither, HLM is unknown (None) and no row
    that needs HLM on or off takes the checkpoint.

    Args:
        meta: the checkpoint's ``meta`` dict.
        config: the checkpoint's ``config`` dict (or None).
        iteration: the checkpoint's training iteration (or None: warm-up not checked).
        frames: the checkpoint's env steps (or None: not recorded).

    Returns:
        the :class:`CheckpointInfo`.
    """
    hlm, vae = meta.get("hlm"), meta.get("vanilla_vae")
    if hlm is None:
        section = (config or {}).get("hlm") or {}
        hlm = section.get("enabled")
        warmup = section.get("warmup_iters")
        # ``iteration`` counts the updates done; update k (0-based) is the first with L_hie when
        # k >= warmup_iters, so a checkpoint at iteration <= warmup_iters has had none
        if hlm and warmup is not None and iteration is not None and int(iteration) <= int(warmup):
            hlm = False  # L_hie had not joined yet
        if vae is None:
            vae = section.get("vanilla_vae")
    hlm = None if hlm is None else bool(hlm)
    vae = None if hlm is None else (bool(hlm) and bool(vae))  # the VAE prior matters only with HLM
    kind = meta.get("kind")
    return CheckpointInfo(robot=meta.get("robot"), kind=kind,
                          perception=meta.get("perception") if kind == "student" else None,
                          hlm=hlm if kind == "student" else None, vanilla_vae=vae if kind == "student" else None,
                          locomotion=meta.get("locomotion", "learned") if kind == "student" else None,
                          frames=None if frames is None else int(frames))


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


def read_info(path: Path, root: str | Path = ".") -> CheckpointInfo:
    """:func:`checkpoint_info` of the checkpoint at ``path`` (loaded to the CPU). Its ``frames``
    count the warm start's too (``checkpoint.init``, :func:`warm_start_frames`, recorded paths read
    under ``root``, the repository root): a student started from another's weights has had their
    env steps of training as well."""
    state = load_checkpoint(path)
    frames = state.get("frames")
    if frames is not None:
        frames = int(frames) + warm_start_frames(state["meta"], root)
    return checkpoint_info(state["meta"], state.get("config"), state.get("iteration"), frames)


@dataclass(frozen=True)
class Resolution:
    """Where a row's checkpoints are.

    Attributes:
        key: the row (a key of :data:`ROWS`).
        path: the first matching checkpoint, or the path that would hold the row.
        found: whether the row has a checkpoint.
        note: what the other candidate files hold, when some exist but do not match.
        paths: every matching checkpoint, one per training seed (empty when not found).
        frames: each one's env steps of training, in the order of ``paths`` (None: not recorded).
    """

    key: str
    path: Path
    found: bool
    note: str = ""
    paths: tuple[Path, ...] = ()
    frames: tuple[int | None, ...] = ()


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
    notes, found, frames = [], [], []
    for rel in spec.paths:
        for path in (sorted(root.glob(rel)) if any(c in rel for c in "*?[") else [root / rel]):
            if not path.is_file() or path in found:
                continue
            info = read(path)
            why = mismatch(spec, info)
            if why is None:
                found.append(path)
                frames.append(info.frames)
            else:
                notes.append(f"{path} holds the {describe(info)}: {why}")
    if found:
        return Resolution(spec.key, found[0], True, "; ".join(notes), paths=tuple(found), frames=tuple(frames))
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
