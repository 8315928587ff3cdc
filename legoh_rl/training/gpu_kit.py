"""The kit a lent GPU machine needs, and a working tree small enough to send it (recipes/gpu_kit.py).

A device call sends the working tree (tracked files, untracked files git does not ignore, carried
paths) up to :data:`TRAVEL_LIMIT`; the machine has torch with CUDA but none of this project's other
packages and no robot models. This module builds the kit (:func:`download_wheels`,
:func:`split_large`, :func:`copy_robot`), takes out of the index what a job does not read and puts
it back (:func:`slim`, :func:`restore`), adds up what a call would send (:func:`travel_bytes`) and
writes the device command (:func:`device_command`). :func:`run_dir_of` is where an experiment's
run lives, for ``recipes/gpu_job.py`` too. docs/gpu_physics.md, "The kit".
"""


from __future__ import annotations

import os
import shutil
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, OmegaConf

from legoh_rl.training.config_store import register_configs

ROOT = Path(__file__).resolve().parents[2]  # the repository
KIT = "gpu_kit"
#: what a device call may send, working tree and carried paths together
TRAVEL_LIMIT = 64 * 2**20
#: packages a lent machine's image lacks (it has torch, numpy, scipy, tqdm, imageio, matplotlib,
#: cloudpickle, packaging, absl-py, etils: docs of the device tool, KINDS.md), installed there
#: with ``--no-deps``; wandb stays out (the GPU experiments log to csv)
KIT_PACKAGES = ("torchrl", "tensordict", "pyvers", "hoptorch", "orjson", "mujoco", "mujoco-core", "mujoco-studio",
                "glfw", "pyopengl", "hydra-core", "omegaconf", "antlr4-python3-runtime", "trimesh", "gymnasium",
                "farama-notifications", "array-api-compat")
#: added by ``build --warp`` for ``env.physics=warp`` (warp-lang's wheel is ~149 MB: more than one
#: call carries, so it is split in parts that the device joins, docs/gpu_physics.md)
WARP_PACKAGES = ("mujoco-warp", "warp-lang")
#: tracked folders that ``slim`` keeps home, but for what the experiment reads
HEAVY = ("runs", "checkpoints", "docs/videos", "docs/img")
EXCLUDE_BEGIN = "# >>> gpu_kit slim (recipes/gpu_kit.py restore removes this block)"
EXCLUDE_END = "# <<< gpu_kit slim"
UNTRACKED_MARK = "# untracked files under them (excluded only):"
PLATFORM = ("--python-version", "3.12", "--implementation", "cp", "--abi", "cp312", "--abi", "abi3",
            "--abi", "none", "--platform", "manylinux_2_28_x86_64", "--platform", "manylinux_2_27_x86_64",
            "--platform", "manylinux_2_17_x86_64", "--platform", "manylinux2014_x86_64", "--platform", "any")


def _git(*args: str, root: Path = ROOT) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True).stdout


def pinned(packages: tuple[str, ...]) -> list[str]:
    """``name==version`` for each package, at the version installed in this environment.

    Raises:
        PackageNotFoundError: a package is not installed here (names it and the extra to install).
    """
    out = []
    for name in packages:
        try:
            out.append(f"{name}=={version(name)}")
        except PackageNotFoundError:
            extra = " (pip install -e '.[gpu]')" if name in WARP_PACKAGES else ""
            raise PackageNotFoundError(f"{name} is not installed here{extra}: the kit takes the installed versions") from None
    return out


def download_wheels(requirements: list[str], out: Path) -> list[Path]:
    """Download cp312 / x86-64 Linux wheels of ``requirements`` (``name==version``) into ``out``,
    without dependencies; a requirement with no such wheel on the index (a pure-Python sdist) is
    built into a wheel here. Returns the wheels in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    pip = [sys.executable, "-m", "pip"]
    for req in requirements:
        got = subprocess.run([*pip, "download", "--no-deps", "--only-binary=:all:", *PLATFORM, "-d", str(out), req],
                             capture_output=True, text=True)
        if got.returncode != 0:
            built = subprocess.run([*pip, "wheel", "--no-deps", "-w", str(out), req], capture_output=True, text=True)
            if built.returncode != 0:
                raise RuntimeError(f"{req}: no cp312 wheel to download and none could be built:\n"
                                   f"{got.stderr[-600:]}\n{built.stderr[-600:]}")
    return sorted(out.glob("*.whl"))


def split_large(paths: list[Path], part_bytes: int) -> list[Path]:
    """Replace each file over ``part_bytes`` by ``<name>.partNN`` files of at most that size (the
    device joins them with ``cat <name>.part* > <name>``). Returns the files there now."""
    result = []
    for path in paths:
        data = path.read_bytes()
        if len(data) <= part_bytes:
            result.append(path)
            continue
        for k, start in enumerate(range(0, len(data), part_bytes)):
            part = path.with_name(f"{path.name}.part{k:02d}")
            part.write_bytes(data[start:start + part_bytes])
            result.append(part)
        path.unlink()
    return result


def copy_robot(robot: str, out: Path) -> Path:
    """Copy the robot's Menagerie folder (``$MENAGERIE_ROOT/<menagerie name>``) into ``out``.

    Raises:
        FileNotFoundError: ``MENAGERIE_ROOT`` unset, or the folder missing there (names it).
    """
    from legoh_rl.envs.robots import get_robot_spec

    root = os.environ.get("MENAGERIE_ROOT")
    if not root:
        raise FileNotFoundError("MENAGERIE_ROOT is not set: the kit copies the robot's model from it "
                                "(export MENAGERIE_ROOT=$(cd ../shared/robots && pwd))")
    name = get_robot_spec(robot).menagerie_name
    source = Path(root) / name
    if not source.is_dir():
        raise FileNotFoundError(f"{source}: no Menagerie folder for robot {robot!r} (MENAGERIE_ROOT={root})")
    target = out / name
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(source, target)
    return target


def experiment_config(experiment: str, overrides: list[str] = ()) -> tuple[str, DictConfig]:
    """``(recipe, config)`` of an experiment, as its recipe composes it with ``overrides``.

    Raises:
        FileNotFoundError: no such experiment file. ValueError: it names no known recipe.
    """
    register_configs()
    path = ROOT / "recipes" / "config" / "experiment" / f"{experiment}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no experiment {experiment!r}")
    recipe = OmegaConf.load(path).get("recipe")
    if recipe not in ("unified", "oracle_ppo"):
        raise ValueError(f"{path} names recipe {recipe!r}; expected unified or oracle_ppo")
    with initialize_config_dir(config_dir=str(ROOT / "recipes" / "config"), version_base=None):
        return recipe, compose(config_name=recipe, overrides=[f"experiment={experiment}", *overrides])


def run_dir_of(experiment: str, overrides: list[str]) -> tuple[str, Path]:
    """``(recipe, checkpoint.dir)`` of an experiment, as its recipe composes it with ``overrides``
    (a relative folder under the repository).

    Raises:
        FileNotFoundError: no such experiment file. ValueError: it names no known recipe.
    """
    recipe, cfg = experiment_config(experiment, overrides)
    run_dir = Path(cfg.checkpoint.dir)
    return recipe, run_dir if run_dir.is_absolute() else ROOT / run_dir


def needed_paths(experiment: str, overrides: list[str] = ()) -> list[str]:
    """The tracked paths an experiment's run reads, relative to the repository: its run folder,
    its ``checkpoint.init`` and, for a student, its teacher (paths outside the repository are left
    out)."""
    _, run_dir = run_dir_of(experiment, list(overrides))
    _, cfg = experiment_config(experiment, list(overrides))
    paths = [run_dir]
    for value in (cfg.checkpoint.get("init"), cfg.get("teacher")):
        if value:
            paths.append(Path(value) if Path(value).is_absolute() else ROOT / value)
    return sorted({str(p.relative_to(ROOT)) for p in paths if p.resolve().is_relative_to(ROOT)})


def slim(keep: list[str], root: Path = ROOT, heavy: tuple[str, ...] = HEAVY) -> list[str]:
    """Untrack every tracked file under ``heavy`` that is not under one of ``keep`` and exclude it
    in ``.git/info/exclude`` (the files stay on disk); exclude the untracked files there alike.
    Returns the paths excluded (the untracked ones, then the new ones).

    Raises:
        RuntimeError: changes are staged (a later ``restore`` resets the index), or the tree is
            slimmed already.
    """
    exclude = root / ".git" / "info" / "exclude"
    if exclude.is_file() and EXCLUDE_BEGIN in exclude.read_text():
        raise RuntimeError(f"{exclude}: the tree is slimmed already (python recipes/gpu_kit.py restore first)")
    if _git("diff", "--cached", "--name-only", root=root).strip():
        raise RuntimeError("changes are staged: commit or unstage them first (restore resets the index of the "
                           "paths slim untracks)")
    keep_paths = [Path(k) for k in keep]

    def unread(listing: str) -> list[str]:
        return [p for p in listing.split("\0") if p and not any(Path(p) == k or Path(p).is_relative_to(k)
                                                               for k in keep_paths)]

    drop = unread(_git("ls-files", "-z", "--", *heavy, root=root))
    # new run folders and files not yet committed would travel too: excluded alike, nothing to untrack
    new = unread(_git("ls-files", "-z", "--others", "--exclude-standard", "--", *heavy, root=root))
    if not drop and not new:
        return []
    for start in range(0, len(drop), 500):
        _git("rm", "-q", "--cached", "--", *drop[start:start + 500], root=root)
    exclude.parent.mkdir(parents=True, exist_ok=True)
    before = exclude.read_text() if exclude.is_file() else ""
    lines = [EXCLUDE_BEGIN, *("/" + p for p in drop), UNTRACKED_MARK, *("/" + p for p in new), EXCLUDE_END]
    exclude.write_text(before + ("" if before.endswith("\n") or not before else "\n") + "\n".join(lines) + "\n")
    return drop + new


def restore(root: Path = ROOT) -> list[str]:
    """Undo :func:`slim`: track the untracked paths again (their index entries from ``HEAD``) and
    remove the exclude block. Returns the paths tracked again (none when the tree was not slimmed)."""
    exclude = root / ".git" / "info" / "exclude"
    text = exclude.read_text() if exclude.is_file() else ""
    if EXCLUDE_BEGIN not in text:
        return []
    head, rest = text.split(EXCLUDE_BEGIN, 1)
    block, _, tail = rest.partition(EXCLUDE_END)
    untracked_before = block.partition(UNTRACKED_MARK)[0]  # after the mark: files that were never tracked
    paths = [line[1:] for line in untracked_before.splitlines() if line.startswith("/")]
    exclude.write_text(head + tail.lstrip("\n"))
    for start in range(0, len(paths), 500):
        _git("reset", "-q", "HEAD", "--", *paths[start:start + 500], root=root)
    return paths


def travel_bytes(carry: list[str], root: Path = ROOT) -> dict:
    """What a device call sends: ``tracked`` (files present), ``untracked`` (not ignored) and
    ``carried`` bytes, their ``total`` and whether it is within :data:`TRAVEL_LIMIT`."""
    def size(names):
        return sum((root / n).stat().st_size for n in names if n and (root / n).is_file())

    tracked = size(_git("ls-files", "-z", root=root).split("\0"))
    untracked = size(_git("ls-files", "-z", "--others", "--exclude-standard", root=root).split("\0"))
    carried = 0
    for c in carry:
        path = root / c
        if path.is_file():
            carried += path.stat().st_size
        elif path.is_dir():
            carried += sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
        else:
            raise FileNotFoundError(f"carry: {path} does not exist (python recipes/gpu_kit.py build)")
    total = tracked + untracked + carried
    return {"tracked": tracked, "untracked": untracked, "carried": carried, "total": total,
            "fits": total <= TRAVEL_LIMIT}


def device_command(experiment: str, seconds: int, overrides: list[str] = ()) -> str:
    """The command a device call runs: install the kit's wheels, point the robot models, the
    prebuilt native kernels (used where the image has no C compiler) and the imports at the copy, train ``experiment`` to the deadline and pack its state into ``$OUT``."""
    extra = " ".join(overrides)
    return (f"set -e; for p in {KIT}/wheels/*.part00; do if [ -e \"$p\" ]; then cat \"${{p%.part00}}\".part* > "
            f"\"${{p%.part00}}\"; fi; done; python -m pip install -q --no-deps {KIT}/wheels/*.whl; "
            f"export MENAGERIE_ROOT=$PWD/{KIT}/robots LEGOH_RL_NATIVE_PREBUILT=$PWD/{KIT}/native PYTHONPATH=$PWD "
            f"WANDB_MODE=offline; "
            f"python recipes/gpu_job.py train --experiment {experiment} --seconds {seconds} --out \"$OUT\""
            + (f" -- {extra}" if extra else ""))
