"""legoh_rl.training.gpu_kit and recipes/gpu_kit.py: the kit a lent GPU machine needs and a working tree
small enough to send."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest

from legoh_rl.training import gpu_kit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes"))

import gpu_job  # noqa: E402
import gpu_kit as gpu_kit_cli  # noqa: E402  (recipes/gpu_kit.py)


def git(root: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True).stdout


@pytest.fixture
def repo(tmp_path):
    """A repository like this one in miniature: code, run states, checkpoints, a video."""
    root = tmp_path / "repo"
    files = {"legoh_rl/a.py": b"x" * 10, "runs/keep/last.pt": b"k" * 100, "runs/other/last.pt": b"o" * 1000,
             "runs/other/snapshots/s.pt": b"s" * 300, "checkpoints/teacher.pt": b"t" * 50,
             "checkpoints/big.pt": b"b" * 2000, "docs/videos/v.mp4": b"v" * 700, "docs/notes.md": b"n" * 7}
    for name, data in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(data)
    git(root.parent, "init", "-q", str(root))
    git(root, "-c", "user.email=t@t", "-c", "user.name=t", "add", "-A")
    git(root, "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-q", "-m", "tree")
    (root / ".git" / "info").mkdir(exist_ok=True)
    (root / ".git" / "info" / "exclude").write_text("# mine\n/.gl/\n")
    return root


def test_slim_sends_only_what_the_job_reads_and_restore_puts_the_index_back(repo):
    before = git(repo, "ls-files")
    assert gpu_kit.travel_bytes([], repo)["total"] == 10 + 100 + 1000 + 300 + 50 + 2000 + 700 + 7
    (repo / "runs/new").mkdir()
    (repo / "runs/new/last.pt").write_bytes(b"u" * 90)  # a run not yet committed: it would travel too
    (repo / "runs/keep/metrics.jsonl").write_bytes(b"m" * 3)  # one the job reads
    dropped = gpu_kit.slim(["runs/keep", "checkpoints/teacher.pt"], repo)
    assert dropped == ["checkpoints/big.pt", "docs/videos/v.mp4", "runs/other/last.pt",
                       "runs/other/snapshots/s.pt", "runs/new/last.pt"]
    assert git(repo, "ls-files").split() == ["checkpoints/teacher.pt", "docs/notes.md", "legoh_rl/a.py",
                                             "runs/keep/last.pt"]
    assert (repo / "runs/other/last.pt").read_bytes() == b"o" * 1000  # still on disk, not sent
    assert git(repo, "status", "--porcelain", "--untracked-files=all").split("\n")[0].startswith("D ")
    t = gpu_kit.travel_bytes([], repo)
    assert (t["tracked"], t["untracked"], t["total"], t["fits"]) == (10 + 100 + 50 + 7, 3, 170, True)
    with pytest.raises(RuntimeError, match="slimmed already"):
        gpu_kit.slim([], repo)
    assert gpu_kit.restore(repo) == dropped[:4]
    assert git(repo, "ls-files") == before
    assert git(repo, "status", "--porcelain") == "?? runs/keep/metrics.jsonl\n?? runs/new/\n"
    assert (repo / ".git" / "info" / "exclude").read_text() == "# mine\n/.gl/\n"  # the user's own lines kept
    assert gpu_kit.restore(repo) == []  # nothing to undo


def test_slim_refuses_while_changes_are_staged(repo):
    (repo / "legoh_rl/a.py").write_bytes(b"changed")
    git(repo, "add", "legoh_rl/a.py")
    with pytest.raises(RuntimeError, match="changes are staged"):
        gpu_kit.slim([], repo)
    assert "gpu_kit slim" not in (repo / ".git" / "info" / "exclude").read_text()


def test_travel_counts_carried_paths_and_refuses_a_missing_one(repo, monkeypatch):
    with (repo / ".git" / "info" / "exclude").open("a") as f:
        f.write("/kit/\n")  # ignored, as gpu_kit/ is here: it travels as a carried path only
    (repo / "kit" / "w").mkdir(parents=True)
    (repo / "kit" / "w" / "a.whl").write_bytes(b"w" * 123)
    (repo / "kit" / "r.xml").write_bytes(b"r" * 5)
    assert gpu_kit.travel_bytes(["kit"], repo)["carried"] == 128
    with pytest.raises(FileNotFoundError, match="gpu_kit.py build"):
        gpu_kit.travel_bytes(["nothing"], repo)
    assert gpu_kit.travel_bytes(["kit"], repo)["fits"]
    assert gpu_kit.travel_bytes(["kit"], repo)["total"] == 4167 + 128
    monkeypatch.setattr(gpu_kit, "TRAVEL_LIMIT", 4294)  # the tree (4,167 bytes) and the kit (128): one over
    assert not gpu_kit.travel_bytes(["kit"], repo)["fits"] and gpu_kit.travel_bytes([], repo)["fits"]


def test_split_parts_are_joined_by_the_device_commands_own_loop(tmp_path):
    wheels = tmp_path / gpu_kit.KIT / "wheels"
    wheels.mkdir(parents=True)
    data = bytes(range(256)) * 41  # 10,496 bytes
    (wheels / "big-1.0-py3-none-any.whl").write_bytes(data)
    (wheels / "small-1.0-py3-none-any.whl").write_bytes(b"s" * 10)
    files = gpu_kit.split_large(sorted(wheels.glob("*.whl")), 4096)
    assert [f.name for f in files] == ["big-1.0-py3-none-any.whl.part00", "big-1.0-py3-none-any.whl.part01",
                                       "big-1.0-py3-none-any.whl.part02", "small-1.0-py3-none-any.whl"]
    assert [f.stat().st_size for f in files] == [4096, 4096, 2304, 10]
    command = gpu_kit.device_command("oracle_g1_real_pits_gpu", 480)
    join = command.split("; python -m pip")[0]  # the part before the install
    subprocess.run(["bash", "-c", join], cwd=tmp_path, check=True)
    assert (wheels / "big-1.0-py3-none-any.whl").read_bytes() == data
    assert "--experiment oracle_g1_real_pits_gpu --seconds 480 --out \"$OUT\"" in command
    assert f"MENAGERIE_ROOT=$PWD/{gpu_kit.KIT}/robots" in command
    assert f"LEGOH_RL_NATIVE_PREBUILT=$PWD/{gpu_kit.KIT}/native" in command  # the kernels built here
    assert gpu_kit.device_command("x", 5, ["env.num_envs=8"]).endswith("-- env.num_envs=8")


def test_the_kit_takes_the_installed_versions_and_names_a_missing_package():
    assert gpu_kit.pinned(("torchrl", "mujoco")) == [f"torchrl=={version('torchrl')}", f"mujoco=={version('mujoco')}"]
    assert gpu_kit.pinned(gpu_kit.KIT_PACKAGES + gpu_kit.WARP_PACKAGES)  # `make test` installs every one
    with pytest.raises(PackageNotFoundError, match="no-such-package is not installed here"):
        gpu_kit.pinned(("no-such-package",))


def test_the_kit_downloads_a_cp312_wheel_and_builds_one_the_index_has_only_as_source(tmp_path):
    """pyvers has a wheel on the index; antlr4-python3-runtime 4.9.3 (hydra's) only a source archive."""
    wheels = gpu_kit.download_wheels(gpu_kit.pinned(("pyvers", "antlr4-python3-runtime")), tmp_path)
    names = sorted(w.name for w in wheels)
    assert len(names) == 2 and names[0].startswith("antlr4_python3_runtime-4.9.3-") and names[1].startswith("pyvers-")
    with pytest.raises(RuntimeError, match="no-such-package==1.0: no cp312 wheel"):
        gpu_kit.download_wheels(["no-such-package==1.0"], tmp_path)


def test_the_robot_model_is_copied_from_menagerie_root(tmp_path, monkeypatch):
    out = gpu_kit.copy_robot("h1", tmp_path)
    assert out.name == "unitree_h1" and (out / "h1.xml").is_file()
    monkeypatch.delenv("MENAGERIE_ROOT")
    with pytest.raises(FileNotFoundError, match="MENAGERIE_ROOT is not set"):
        gpu_kit.copy_robot("h1", tmp_path)
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path / "none"))
    with pytest.raises(FileNotFoundError, match="no Menagerie folder for robot 'g1'"):
        gpu_kit.copy_robot("g1", tmp_path)


def test_slim_keeps_the_files_each_job_reads():
    assert gpu_kit.needed_paths("oracle_g1_real_pits_gpu") == [
        "runs/oracle_g1_foot_scan/snapshots/frames030001152.pt", "runs/oracle_g1_real_pits_gpu"]
    assert gpu_kit.needed_paths("student_h1_real_pits") == ["checkpoints/oracle_h1_real_pits.pt", "runs/student_h1_real_pits"]
    assert gpu_kit.needed_paths("student_h1_real_pits_gpu") == ["checkpoints/oracle_h1_real_pits.pt",
                                                               "runs/student_h1_real_pits_gpu"]


def test_the_command_line_prints_the_device_command_and_gpu_job_finds_the_same_run(capsys):
    assert gpu_kit_cli.main(["command", "--experiment", "oracle_g1_real_pits_gpu", "--seconds", "300",
                             "env.num_envs=512"]) == 0
    assert capsys.readouterr().out.strip() == gpu_kit.device_command("oracle_g1_real_pits_gpu", 300,
                                                                     ["env.num_envs=512"])
    assert gpu_job.run_dir_of("oracle_g1_real_pits_gpu", []) == ("oracle_ppo", ROOT / "runs" / "oracle_g1_real_pits_gpu")


def test_the_job_says_whether_the_native_kernels_load(monkeypatch):
    from legoh_rl.envs.native.build import load_library

    lib = load_library()
    assert lib is not None and gpu_job.native_status() == f"native kernels: {lib._name}"
    monkeypatch.setenv("LEGOH_RL_NATIVE", "0")
    assert gpu_job.native_status() == "native kernels unavailable: disabled by LEGOH_RL_NATIVE=0"
