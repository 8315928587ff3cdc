"""Atomic, resumable checkpoints.

A checkpoint is one ``torch.save`` file holding everything a run needs to continue: model and
optimiser states, schedulers, env state (curriculum, rng, counters), torch and numpy RNG states,
the iteration and frame counters, the logger's run id, and a ``meta`` block (robot, observation
layout, action size, kind of policy) that loaders check before using it.

Writes go to a temporary file in the same folder, are flushed to disk, then renamed over the
target: a run killed while writing leaves the previous checkpoint intact. A write that fails (a
full disk, no permission) leaves it intact too, and says so: :class:`CheckpointWriteError` names
the file, the folder and what to do.

Checkpoints are safe to share: they load with ``torch.load(weights_only=True)``, which builds
tensors, plain containers (dict, list, tuple), numbers and strings and nothing else, so a file
whose pickle would call a function (``os.system``, ...) is refused before anything in it runs
(:func:`load_checkpoint`). What :func:`save_checkpoint` writes keeps to that: numpy arrays become
tensors, numpy scalars Python numbers, and a payload holding any other object is refused at
save time rather than written as a file no run could load. Run states written before this rule
hold two kinds of numpy array (curriculum levels, the numpy RNG key): :data:`LEGACY_SAFE_GLOBALS`
lets exactly those through. Weights are checked too: a NaN or inf in any of a checkpoint's
network weights (:data:`WEIGHT_KEYS`) refuses it, naming the tensor.
"""

from __future__ import annotations

import copy
import errno
import hashlib
import os
import pickle
import random
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from legoh_rl.training.weight_average import saved_average

__all__ = [
    "save_checkpoint", "load_checkpoint", "check_meta", "rng_state", "set_rng_state", "resume_path", "export_policy",
    "CheckpointError", "CheckpointWriteError", "require_training_state", "load_weights", "file_digest",
    "LEGACY_SAFE_GLOBALS", "WEIGHT_KEYS", "check_finite_weights", "widen_input_columns", "RENAMED",
    "recorded_checkpoint", "warm_start_frames",
]

#: The only globals :func:`load_checkpoint` allows beyond torch's weights-only set (tensors, plain
#: containers, numbers, strings): numpy's array rebuild, for run states written before
#: :func:`save_checkpoint` stored numpy arrays as tensors. Those hold two kinds of numpy array,
#: int64 (curriculum levels) and uint32 (the numpy MT19937 key of :func:`rng_state`); arrays of
#: any other dtype (object arrays above all) stay refused.
LEGACY_SAFE_GLOBALS = (np._core.multiarray._reconstruct, np.ndarray, np.dtype,
                       np.dtypes.Int64DType, np.dtypes.UInt32DType)

#: The payload entries that hold network weights (``state_dict``\ s): oracle ``networks``, the
#: oracle recipe's ``loss`` (its actor and critic) and ``actor``; a student's ``perception``,
#: ``actor``, ``critic`` and ``vae``. :func:`load_checkpoint` refuses a NaN or inf in any of them.
WEIGHT_KEYS = ("networks", "actor", "perception", "critic", "vae", "loss")


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file, hex (identifies a checkpoint: a student's teacher, a branch point, an
    evaluated policy)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


#: Recorded paths of committed checkpoints that were later renamed: the path a run's record holds
#: -> (the path of that file today, its sha256), so that records made before a rename still open
#: the file they meant. Later renames need no entry: such files are found by their digest (see
#: :func:`recorded_checkpoint`).
RENAMED = {"checkpoints/oracle_h1.pt": ("checkpoints/oracle_h1_clocked.pt",
                                        "6f815f70da0d4dd2b107ca40b6b68046c113b864a0599ac707424458396194ff"),
           "checkpoints/oracle_g1_trails.pt": ("checkpoints/oracle_g1_trails_clocked.pt",
                                               "a8f9139860ce04ee29e68bc8468b3eb982e76eb4009a5cdb97476ac795386049")}


def recorded_checkpoint(path: str, digest: str | None = None, root: str | os.PathLike = ".") -> str:
    """The file a run's record means by ``path`` (a teacher, a warm start), as a path to open.

    With the file's recorded ``digest`` (run states and, since the rename, exports record their
    teacher's), the file is found by content: ``path`` itself when it still holds those bytes, else
    the renamed file of :data:`RENAMED`, else any ``*.pt`` beside ``path`` that does; ``path`` when
    none does (the caller then names the mismatch). Without a digest (records older than
    the rename), a path in :data:`RENAMED` means its file's name today. Relative paths are read
    under ``root``; the answer keeps the form of ``path``'s entry (relative stays relative).

    Args:
        path: the recorded path, e.g. ``"checkpoints/oracle_h1.pt"``.
        digest: the recorded sha256 (hex) of the file meant, or None.
        root: the folder relative paths are read from (the repository root).
    """
    base = Path(root)
    here = lambda p: Path(p) if Path(p).is_absolute() else base / p  # noqa: E731
    renamed = RENAMED.get(str(path))
    if digest is None:
        return renamed[0] if renamed else str(path)
    if here(path).is_file() and file_digest(here(path)) == digest:
        return str(path)
    if renamed and renamed[1] == digest:
        return renamed[0]
    folder = here(path).parent
    for other in sorted(folder.glob("*.pt")) if folder.is_dir() else []:
        if file_digest(other) == digest:
            return str(Path(path).parent / other.name)
    return str(path)


def warm_start_frames(meta: dict, root: str | os.PathLike = ".", _depth: int = 0) -> int:
    """Env steps of training behind a run's warm start: the checkpoint it was initialised from
    (``meta["initialised_from"]``, :mod:`recipes/unified.py`'s ``checkpoint.init``), that one's own
    warm start, and so on down the chain; 0 for a run trained from scratch.

    Each link counts the ``frames`` its record holds; the file is found by its recorded digest
    (:func:`recorded_checkpoint`) and read for the next link. Where it is not found (a state left
    out of git, a file changed since), the chain stops at that link's recorded frames: the sum is
    then a lower bound. A chain longer than 16 links is refused as a loop.

    Args:
        meta: a checkpoint's ``meta`` dict.
        root: the folder recorded relative paths are read from (the repository root).

    Returns:
        the env steps, an int >= 0.
    """
    init = meta.get("initialised_from")
    if not init:
        return 0
    if _depth >= 16:
        raise CheckpointError(f"the warm-start chain through {init.get('checkpoint')!r} is longer than 16 links")
    frames = int(init.get("frames") or 0)
    digest = init.get("sha256")
    rel = recorded_checkpoint(init["checkpoint"], digest, root)
    path = Path(rel) if Path(rel).is_absolute() else Path(root) / rel
    if not path.is_file() or (digest is not None and file_digest(path) != digest):
        return frames
    return frames + warm_start_frames(load_checkpoint(path)["meta"], root, _depth + 1)


class CheckpointError(ValueError):
    """A file that is not a usable checkpoint for what was asked (the message names the file)."""


class CheckpointWriteError(OSError, CheckpointError):
    """A checkpoint could not be written (a full disk, no permission, ...): the message names the
    file, its folder, what to do, and whether the previous checkpoint there is intact. An
    :class:`OSError` (``errno`` kept: ``ENOSPC`` for a full disk) and a :class:`CheckpointError`."""


def rng_state() -> dict:
    """Torch, numpy-global and python RNG states, and the CUDA generators' (``"cuda"``, one per GPU)
    when CUDA is in use: a run on a GPU samples its actions there."""
    kind, key, pos, has_gauss, gauss = np.random.get_state()
    numpy_state = {"bit_generator": str(kind), "key": key.tolist(), "pos": int(pos), "has_gauss": int(has_gauss),
                   "gauss": float(gauss)}  # plain numbers, so that a checkpoint loads with weights_only=True
    state = {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    """Restore :func:`rng_state`; the CUDA states only where this machine has as many GPUs (a GPU
    run resumed on a CPU goes on with the CPU generators alone). The numpy state is either the
    plain dict :func:`rng_state` writes or, in older checkpoints, ``np.random.get_state()``'s tuple."""
    torch.set_rng_state(state["torch"])
    numpy_state = state["numpy"]
    if isinstance(numpy_state, dict):
        numpy_state = (numpy_state["bit_generator"], np.asarray(numpy_state["key"], dtype=np.uint32),
                       numpy_state["pos"], numpy_state["has_gauss"], numpy_state["gauss"])
    np.random.set_state(numpy_state)
    random.setstate(state["python"])
    cuda = state.get("cuda")
    if cuda is not None and torch.cuda.is_available() and torch.cuda.device_count() == len(cuda):
        torch.cuda.set_rng_state_all(cuda)


def _plain(obj: Any) -> Any:
    """``obj`` with numpy arrays as tensors (other dtypes: lists) and numpy scalars as Python
    numbers, at any depth of dicts, lists and tuples: what ``torch.load(weights_only=True)`` builds
    without allowing numpy's globals. Containers with nothing to convert are returned as they are
    (a ``state_dict``'s ``OrderedDict`` keeps its ``_metadata``)."""
    if isinstance(obj, np.ndarray):
        try:  # bool, integers, floats, complex: a tensor of the same dtype
            return torch.from_numpy(np.array(obj, copy=True, order="C"))
        except TypeError:  # strings, objects, dates, long doubles: Python values
            return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        items = {k: _plain(v) for k, v in obj.items()}
        if all(items[k] is v for k, v in obj.items()):
            return obj
        out = copy.copy(obj)
        out.update(items)
        return out
    if type(obj) in (list, tuple):
        items = [_plain(v) for v in obj]
        if all(a is b for a, b in zip(items, obj, strict=True)):
            return obj
        return type(obj)(items)
    return obj


def _write_error(path: Path, err: BaseException, existed: bool) -> CheckpointWriteError:
    """The :class:`CheckpointWriteError` for a failed write of ``path``: what failed, the free
    space of its folder, what to do, and whether the previous checkpoint is intact."""
    folder = path.parent
    code = getattr(err, "errno", None)
    if code is None and isinstance(err, RuntimeError):  # torch's zip writer: "enforce fail ... file write failed"
        code = errno.EIO
    try:
        free = f"{shutil.disk_usage(folder).free / 1e6:.0f} MB free"
    except OSError:
        free = "free space unknown"
    full = code in (errno.ENOSPC, errno.EDQUOT)
    todo = (f"free space in {folder} ({free}; a checkpoint here takes about the size of the last one) or point "
            "checkpoint.dir at a disk with room" if full else
            f"check that {folder} is writable and its disk healthy ({free}), or point checkpoint.dir elsewhere")
    before = (f"the previous checkpoint at {path} is intact: resume from it (checkpoint.resume=auto) once fixed"
              if existed else f"no earlier checkpoint was at {path}")
    reason = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else err!r}"
    return CheckpointWriteError(code if code is not None else errno.EIO,
                                f"could not write the checkpoint {path} ({reason}): {todo}; {before}")


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` atomically (temp file + fsync + rename); return the path.

    Numpy arrays and scalars anywhere in ``payload`` are written as tensors and Python numbers
    (:func:`_plain`), so that the file loads with ``weights_only=True`` (:func:`load_checkpoint`).

    Raises:
        CheckpointWriteError: the file could not be written (full disk: ``errno.ENOSPC``; torch's
            "PytorchStreamWriter ... file write failed" too): names the file, the folder's free
            space and what to do; the previous checkpoint at ``path``, if any, is left intact.
        CheckpointError: ``payload`` holds an object that :func:`load_checkpoint` would refuse
            (anything but tensors, plain containers, numbers and strings): a bug of the caller,
            refused before the file replaces the previous one.
    """
    path = Path(path)
    existed = path.is_file()
    payload = _plain(payload)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    except OSError as err:
        raise _write_error(path, err, existed) from err
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        unsafe = torch.serialization.get_unsafe_globals_in_checkpoint(tmp)
        if unsafe:
            raise CheckpointError(f"save_checkpoint({path}): the payload holds {sorted(unsafe)}, which a checkpoint "
                                  "may not hold (it loads with weights_only=True): store tensors, plain containers, "
                                  "numbers and strings instead (e.g. a dataclass as dataclasses.asdict, a path as str)")
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; a checkpoint is an ordinary shareable file
        os.replace(tmp, path)
    except BaseException as err:
        try:
            if os.path.exists(tmp):
                os.unlink(tmp)
        except OSError:
            pass
        if isinstance(err, OSError) or (isinstance(err, RuntimeError) and _is_write_failure(err)):
            raise _write_error(path, err, existed) from err
        raise
    return path


def _is_write_failure(err: RuntimeError) -> bool:
    """Whether a ``RuntimeError`` from ``torch.save`` is its zip writer failing to write (a full
    disk shows as ``enforce fail at inline_container.cc ... PytorchStreamWriter failed writing
    file ...: file write failed``), not a bug in the payload."""
    text = str(err)
    return "PytorchStreamWriter" in text or "file write failed" in text or "unexpected pos" in text


#: what torch's weights-only unpickler says of a global it refused to call or a type it refused to
#: build (``Unsupported global: GLOBAL os.system ...``, ``... but got <class 'numpy.dtypes.ObjectDType'>``)
_UNSAFE = re.compile(r"GLOBAL ([\w.]+)|but got <class '([\w.]+)'>")


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint`.

    Every tensor is loaded to the CPU (``map_location="cpu"``), wherever it was saved from: a
    checkpoint of a GPU run loads on a machine without one, and the recipes move what they load
    to their ``device`` (``load_state_dict`` into modules already there; optimisers cast their state
    to their parameters' device).

    Raises:
        FileNotFoundError: no file at ``path`` (the message names it).
        CheckpointError: the file is empty, truncated or not a checkpoint; its pickle would build
            or call anything but tensors, plain containers and numbers (``weights_only=True``: a
            shared file cannot run code here; the message names the function it would have
            called); or a network weight (:data:`WEIGHT_KEYS`) holds a NaN or inf (names the
            tensor). Every message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        with torch.serialization.safe_globals(list(LEGACY_SAFE_GLOBALS)):
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # EOFError, UnpicklingError, zip errors, ...: all mean the same to a user
        size = path.stat().st_size
        text = str(err)
        unsafe = _UNSAFE.search(text) if isinstance(err, pickle.UnpicklingError) else None
        if unsafe:
            name = unsafe.group(1) or unsafe.group(2)
            raise CheckpointError(
                f"{path} refused: loading it would build or call {name}, which no legoh-rl checkpoint "
                "holds (checkpoints load with weights_only=True: tensors, plain containers and numbers only, so "
                "that a shared file cannot run code). Nothing in it was run. Do not use it: ask whoever shared it "
                "for a checkpoint written by this project's recipes (or recipes/export_policy.py)") from None
        reason = " ".join(line.strip() for line in text.splitlines() if line.strip() and not line.startswith(
            ("Weights only load failed", "Please file an issue", "Check the documentation"))) or repr(err)
        raise CheckpointError(f"{path} ({size} bytes) is not a readable checkpoint ({type(err).__name__}: "
                              f"{reason}); it may be empty or cut short: point to another file, or delete it") from None
    if not isinstance(state, dict) or "meta" not in state:
        raise CheckpointError(f"{path} is not a legoh-rl checkpoint (no 'meta' block)")
    check_finite_weights(state, path)
    return state


def check_finite_weights(state: dict, path: str | os.PathLike) -> None:
    """Refuse a checkpoint with a NaN or inf in any network weight (:data:`WEIGHT_KEYS`): a policy
    with one outputs non-finite actions, which an evaluation would report as a bad policy.

    Raises:
        CheckpointError: names the file, the tensor (``actor.mlp.0.weight``) and how many of its
            values are not finite.
    """
    for key in WEIGHT_KEYS:
        block = state.get(key)
        if not isinstance(block, dict):
            continue
        for name, value in block.items():
            if torch.is_tensor(value) and value.is_floating_point() and not bool(torch.isfinite(value).all()):
                bad = int((~torch.isfinite(value)).sum())
                raise CheckpointError(
                    f"{path}: weight {key}.{name} holds {bad} non-finite value(s) (NaN or inf) of {value.numel()}: "
                    "the run that wrote it diverged, and a policy with such weights acts with NaN. Use an earlier "
                    "checkpoint of that run (or retrain from one)")


def require_training_state(state: dict, path: str | os.PathLike, keys: tuple[str, ...]) -> None:
    """Refuse to resume from a file without the training state ``keys`` (a slim policy export).

    Raises:
        CheckpointError: names the file, the missing keys and what to use instead.
    """
    missing = [k for k in keys if k not in state]
    if missing:
        raise CheckpointError(f"{path} holds no training state (missing {missing}): it is a policy export, which "
                              "cannot be resumed. Resume from a run's last.pt, or start a new run from its weights "
                              f"with checkpoint.init={path}")


def load_weights(module: torch.nn.Module, weights: dict, path: str | os.PathLike, what: str, hint: str) -> None:
    """``module.load_state_dict(weights)`` with an error that names the file and the config to fix.

    Raises:
        CheckpointError: the shapes or names differ (``what`` names the part, ``hint`` the setting).
    """
    own = module.state_dict()
    bad = [f"{k}: checkpoint {tuple(v.shape)}, this run {tuple(own[k].shape)}" for k, v in weights.items()
           if k in own and torch.is_tensor(v) and tuple(v.shape) != tuple(own[k].shape)]
    missing = sorted(set(own) - set(weights))
    unexpected = sorted(set(weights) - set(own))
    if bad or missing or unexpected:
        parts = ([f"size mismatch {'; '.join(bad[:2])}"] if bad else []) + (
            [f"missing {missing[:3]}"] if missing else []) + ([f"unexpected {unexpected[:3]}"] if unexpected else [])
        raise CheckpointError(f"{path}: its {what} do not fit this run's ({'; '.join(parts)}); {hint}")
    module.load_state_dict(weights)


def widen_input_columns(weights: dict, own: dict, keys, path: str | os.PathLike) -> tuple[dict, dict]:
    """A checkpoint's state dict ``weights`` fitted to layers ``keys`` of this run (``own``, its
    state dict) that read more input columns: each such weight ``(out, k_old)`` becomes
    ``(out, k_new)``, its first ``k_old`` columns the checkpoint's and the ``k_new - k_old`` new
    ones (inputs appended after the old ones) zero, so that the layer's output ignores the new
    inputs and the network computes the checkpoint's function of the old ones. Every other entry
    is kept as it is (:func:`load_weights` then checks the rest).

    Args:
        weights: the checkpoint's state dict (not modified).
        own: this run's state dict (the shapes to fit; its values are not read).
        keys: the weight names that may be widened (e.g.
            :func:`~legoh_rl.modules.oracle.scandot_input_keys`).
        path: the checkpoint, for the messages.

    Returns:
        ``(weights, widened)``: the fitted state dict (a new dict; widened tensors are new) and
        ``{key: [old shape, new shape]}`` of each widened weight (plain lists: a meta block's).

    Raises:
        CheckpointError: one of ``keys`` missing from either side, with another number of rows,
            or with fewer columns in this run than in the checkpoint (names the key and both shapes).
    """
    out, widened = dict(weights), {}
    for key in keys:
        if key not in weights or key not in own:
            raise CheckpointError(f"{path}: cannot widen {key}: {'the checkpoint' if key not in weights else 'this run'} "
                                  "has no such weight")
        old, new = weights[key], own[key]
        if tuple(old.shape) == tuple(new.shape):
            continue
        if old.ndim != 2 or new.ndim != 2 or old.shape[0] != new.shape[0] or old.shape[1] > new.shape[1]:
            raise CheckpointError(f"{path}: cannot widen {key} from the checkpoint's {tuple(old.shape)} to this run's "
                                  f"{tuple(new.shape)}: widening adds input columns (same rows, more columns) only")
        wide = torch.zeros(tuple(new.shape), dtype=old.dtype)
        wide[:, : old.shape[1]] = old  # the new columns stay zero: the layer ignores the new inputs
        out[key] = wide
        widened[key] = [list(old.shape), list(new.shape)]
    return out, widened


def check_meta(meta: dict, expected: dict, path: str | os.PathLike = "checkpoint") -> None:
    """Refuse a checkpoint made for another robot, observation layout or policy kind.

    Raises:
        ValueError: naming each mismatching field with both values.
    """
    bad = [f"{k}: checkpoint has {meta.get(k)!r}, this run needs {v!r}" for k, v in expected.items() if meta.get(k) != v]
    if bad:
        raise ValueError(f"{path} does not fit this run: " + "; ".join(bad))


def resume_path(resume: str | None, run_dir: str | os.PathLike) -> Path | None:
    """The checkpoint a run continues from: ``None`` (fresh run), ``"auto"`` (``run_dir/last.pt``
    if it exists) or a path, which must exist.

    Raises:
        FileNotFoundError: an explicit path with no checkpoint (the message names it).
    """
    if resume is None:
        return None
    if resume == "auto":
        last = Path(run_dir) / "last.pt"
        return last if last.is_file() else None
    if not Path(resume).is_file():
        raise FileNotFoundError(f"checkpoint.resume: no checkpoint at {resume}")
    return Path(resume)


#: what a policy needs for inference (evaluate.py, the unified recipe's teacher), and what a run
#: started from it reads of its lineage (its config, frames and gait feedforward schedule:
#: ``feedforward_anneal=inherit``, :mod:`legoh_rl.training.schedules`)
POLICY_KEYS = ("meta", "oracle_config", "networks", "perception", "actor", "config", "iteration", "frames",
               "feedforward_schedule")


def export_policy(src: str | os.PathLike, dst: str | os.PathLike, provenance: dict | None = None,
                  weights: dict | None = None, average: bool = False) -> Path:
    """Write a slim copy of a training checkpoint: the policy without optimisers, env or RNG state.

    The result loads wherever the full checkpoint does for inference (``evaluate.py``, or as the
    teacher of ``unified.py``), and is small enough to commit. ``provenance`` (``experiment``,
    ``stage``, or ``weights`` naming an average) is written into its meta block, for checkpoints
    trained before runs recorded it. ``weights`` (``{"perception": state dict, "actor": ...}``)
    replaces those entries: a weight average's snapshot
    (:class:`~legoh_rl.training.weight_average.PolicyAverage`). A student's teacher digest
    (``teacher_sha256``) goes into the meta block, so its teacher is found by content after a
    rename (:func:`recorded_checkpoint`). ``average``: the weights are the moving average the
    training checkpoint saved (``checkpoint.ema_decay``), e.g. of a run's end between snapshots.

    Raises:
        CheckpointError: ``weights`` names an entry the checkpoint does not hold; ``average`` for a
            checkpoint without a weight average (or with ``weights`` too).
    """
    state = load_checkpoint(src)
    if average:
        if weights is not None:
            raise CheckpointError("export_policy: pass weights or average, not both")
        weights = saved_average(state)
        if weights is None:
            raise CheckpointError(f"{src} holds no weight average (its run had no checkpoint.ema_decay, "
                                  "or it is already a slim policy): export it without --weights average")
        decay = state["weight_average"]["decay"]
        provenance = {"weights": f"ema {decay}", **(provenance or {})}
    slim = {k: state[k] for k in POLICY_KEYS if k in state}
    if state.get("teacher_sha256"):  # a student's teacher, by content: the path in its config may be renamed
        slim["meta"] = {**slim.get("meta", {}), "teacher_sha256": state["teacher_sha256"]}
    if provenance:
        slim["meta"] = {**slim.get("meta", {}), **provenance}
    for key, value in (weights or {}).items():
        if key not in slim:
            raise CheckpointError(f"{src} holds no {key!r} weights to replace (it has {sorted(slim)})")
        slim[key] = value
    return save_checkpoint(dst, slim)
