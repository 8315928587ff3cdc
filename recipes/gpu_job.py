"""Train a run until a deadline on a lent machine, then pack its state to bring back; unpack it here.

A lent GPU machine runs one command of at most 10 minutes and returns at most 8 files of 16 MiB
from its ``$OUT`` folder. This script is the two ends of such a call:

    # there: resume (or start) the experiment's run, stop it with SIGTERM at the deadline (the run
    # writes its checkpoint on the signal), pack last.pt in 15 MiB parts, metrics.jsonl, the
    # newest snapshot and a manifest of SHA-256s into $OUT
    python recipes/gpu_job.py train --experiment student_h1_trails_gpu --seconds 480 --out "$OUT"

    # here: check the parts against the manifest, join them and put the run back in its folder
    python recipes/gpu_job.py unpack --files <the call's files_at folder> --run-dir runs/student_h1_trails_gpu

Extra hydra overrides follow ``--``: ``... --seconds 480 --out "$OUT" -- env.num_threads=16``.
The run folder is the experiment's ``checkpoint.dir`` (the working tree travels with it, so a run
committed here resumes there).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from legoh_rl.training.gpu_kit import run_dir_of

ROOT = Path(__file__).resolve().parents[1]
#: the largest file a lent machine hands back is 16 MiB: parts stay under it
PART_BYTES = 15 * 1024 * 1024
#: files back from a call, at most (last.pt's parts, metrics, snapshot, manifest)
MAX_FILES = 8
MANIFEST = "manifest.json"


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def native_status() -> str:
    """One line on the native kernels on this machine: loaded from where, or why not."""
    from legoh_rl.envs.native.build import load_library, unavailable_reason

    lib = load_library()
    return f"native kernels: {lib._name}" if lib is not None else f"native kernels unavailable: {unavailable_reason()}"


def train(experiment: str, seconds: float, overrides: list[str]) -> tuple[Path, int]:
    """Run ``recipes/<recipe>.py experiment=<experiment> checkpoint.resume=auto`` for at most
    ``seconds``; at the deadline send SIGTERM and wait for the run's checkpoint. Returns the run
    folder and the recipe's exit code (143 after a SIGTERM stop)."""
    recipe, run_dir = run_dir_of(experiment, overrides)
    cmd = [sys.executable, str(ROOT / "recipes" / f"{recipe}.py"), f"experiment={experiment}",
           "checkpoint.resume=auto", *overrides]
    print("running:", " ".join(cmd), flush=True)
    proc = subprocess.Popen(cmd, cwd=ROOT)
    try:
        proc.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGTERM)  # the run checkpoints and exits (legoh_rl/training/interrupt.py)
        try:
            proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return run_dir, proc.returncode


def pack(run_dir: Path, out: Path) -> dict:
    """Copy the run's state into ``out``: ``last.pt`` in parts of at most :data:`PART_BYTES`,
    ``metrics.jsonl``, the newest snapshot, and :data:`MANIFEST` (names, SHA-256s, the parts'
    order). Returns the manifest.

    Raises:
        FileNotFoundError: the run folder holds no ``last.pt``.
        ValueError: the state needs more than :data:`MAX_FILES` files.
    """
    last = run_dir / "last.pt"
    if not last.is_file():
        raise FileNotFoundError(f"{last}: no checkpoint to bring back (did the run start?)")
    out.mkdir(parents=True, exist_ok=True)
    data = last.read_bytes()
    parts = []
    for k, start in enumerate(range(0, len(data), PART_BYTES)):
        name = f"last.pt.part{k:02d}"
        (out / name).write_bytes(data[start:start + PART_BYTES])
        parts.append(name)
    manifest = {"run_dir": str(run_dir.relative_to(ROOT)) if run_dir.is_relative_to(ROOT) else str(run_dir),
                "last.pt": {"sha256": hashlib.sha256(data).hexdigest(), "parts": parts}, "files": {}}
    extra = [run_dir / "metrics.jsonl"]
    snapshots = sorted((run_dir / "snapshots").glob("*.pt")) if (run_dir / "snapshots").is_dir() else []
    extra += snapshots[-1:]
    for path in extra:
        if path.is_file():
            shutil.copyfile(path, out / path.name)
            manifest["files"][path.name] = {"sha256": sha256(path),
                                            "to": str(path.relative_to(run_dir))}
    count = len(parts) + len(manifest["files"]) + 1
    if count > MAX_FILES:
        raise ValueError(f"{run_dir}: its state needs {count} files, more than the {MAX_FILES} a call brings back "
                         f"(last.pt is {len(data) / 2**20:.1f} MiB: shrink the replay window, dagger_replay.capacity)")
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return manifest


def unpack(files: Path, run_dir: Path) -> Path:
    """Join and check what :func:`pack` wrote (in ``files``) into ``run_dir``: ``last.pt``,
    ``metrics.jsonl`` and the snapshot under ``snapshots/``. A ``last.pt`` already there is kept
    as ``last.pt.before-unpack``. Returns the joined ``last.pt``.

    Raises:
        FileNotFoundError: no manifest or a missing part (names it).
        ValueError: a file whose SHA-256 is not the manifest's (names it).
    """
    manifest_path = files / MANIFEST
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{manifest_path}: no manifest (not the output of gpu_job.py train)")
    manifest = json.loads(manifest_path.read_text())
    chunks = []
    for name in manifest["last.pt"]["parts"]:
        if not (files / name).is_file():
            raise FileNotFoundError(f"{files / name}: a part of last.pt is missing")
        chunks.append((files / name).read_bytes())
    data = b"".join(chunks)
    if hashlib.sha256(data).hexdigest() != manifest["last.pt"]["sha256"]:
        raise ValueError(f"{files}: the joined last.pt does not match the manifest's SHA-256 (a damaged part)")
    for name, entry in manifest["files"].items():
        target = (run_dir / entry["to"]).resolve()
        if Path(name).name != name or not target.is_relative_to(run_dir.resolve()):
            raise ValueError(f"{manifest_path}: entry {name!r} -> {entry['to']!r} leaves the run folder {run_dir}")
        if sha256(files / name) != entry["sha256"]:
            raise ValueError(f"{files / name}: SHA-256 differs from the manifest's")
    run_dir.mkdir(parents=True, exist_ok=True)
    last = run_dir / "last.pt"
    if last.is_file():
        last.replace(run_dir / "last.pt.before-unpack")
    tmp = run_dir / "last.pt.unpack.tmp"
    tmp.write_bytes(data)
    tmp.replace(last)
    for name, entry in manifest["files"].items():
        target = run_dir / entry["to"]
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(files / name, target)
    return last


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    overrides = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train", help="train until the deadline, then pack the run's state into --out")
    t.add_argument("--experiment", required=True)
    t.add_argument("--seconds", type=float, required=True, help="the deadline, from the start of the run")
    t.add_argument("--out", type=Path, required=True)
    u = sub.add_parser("unpack", help="put a packed state back into a run folder")
    u.add_argument("--files", type=Path, required=True)
    u.add_argument("--run-dir", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.command == "train":
        if args.seconds <= 0:
            parser.error(f"--seconds must be positive, got {args.seconds}")
        started = time.monotonic()
        print(native_status(), flush=True)  # the march falls back to torch (slower) without the kernels
        run_dir, code = train(args.experiment, args.seconds, overrides)
        manifest = pack(run_dir, args.out)
        print(f"trained {time.monotonic() - started:.0f} s (exit {code}); packed {len(manifest['last.pt']['parts'])} "
              f"part(s) of last.pt and {sorted(manifest['files'])} into {args.out}")
        return 0 if code in (0, 128 + signal.SIGTERM) else code
    last = unpack(args.files, args.run_dir)
    print(f"unpacked {last}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
