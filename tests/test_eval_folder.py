"""An evaluation's output folder belongs to one evaluation at a time (issue 50, part 4).

A second evaluation into a folder where one is running is refused with the running one's pid; a
folder that holds an earlier evaluation's files is refused unless ``overwrite=true``, which moves
them into ``overwritten-<time>/`` first; a training run's folder is refused.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from legoh_rl.training.run_dir import RunDirError, open_eval_dir

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes"))
from legoh_rl.training import eval_run  # noqa: E402

TINY = ["checkpoint=zero", "categories=[randommix]", "levels=[0]", "robots_per_cell=1", "variants=1",
        "num_threads=1", "device=cpu", "video=false", "logger.backend=csv"]


def cfg_of(overrides):
    with initialize_config_dir(config_dir=str(ROOT / "recipes" / "config"), version_base=None):
        return compose(config_name="evaluate", overrides=overrides)


def test_a_second_evaluation_into_a_running_ones_folder_is_refused_with_its_pid(tmp_path, monkeypatch):
    out = tmp_path / "eval"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import fcntl, os, sys, time
        fd = os.open({str(out / 'eval.lock')!r}, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, f"{{os.getpid()}}\\n".encode())
        print("locked", flush=True)
        sys.stdin.read()  # until the test closes it
    """)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        built = []
        monkeypatch.setattr(eval_run, "load_policy", lambda *a, **k: built.append(1))
        with pytest.raises(RunDirError, match=rf"another evaluation \(pid {holder.pid}\) is writing into "
                                              rf"{out}: wait for it to finish, stop it, or choose another output_dir"):
            eval_run.evaluate(cfg_of(TINY + [f"output_dir={out}"]))
        assert not built and list(out.iterdir()) == [out / "eval.lock"]  # nothing written beside the lock
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    with open_eval_dir(out):  # the holder gone, the kernel dropped its lock: the folder is free again
        pass


def test_a_folder_with_results_is_refused_unless_overwrite_moves_them_aside(tmp_path):
    out = tmp_path / "eval"
    first = eval_run.evaluate(cfg_of(TINY + [f"output_dir={out}"]))
    table = Path(first["table"]).read_text()
    assert (out / eval_run.RECORD_NAME).is_file()
    with pytest.raises(RunDirError, match=rf"output_dir={out} holds an earlier evaluation's results "
                                          r"\(episodes.csv, evaluated_with.json, logs, table.csv, .*\); a new evaluation would mix "
                                          r"its files with them. Start over with overwrite=true"):
        eval_run.evaluate(cfg_of(TINY + [f"output_dir={out}", "levels=[1]"]))
    assert Path(first["table"]).read_text() == table  # untouched
    second = eval_run.evaluate(cfg_of(TINY + [f"output_dir={out}", "levels=[1]", "overwrite=true"]))
    aside = [p for p in out.iterdir() if p.name.startswith("overwritten-")]
    assert len(aside) == 1 and (aside[0] / "table.md").read_text() == table  # the first evaluation, whole
    assert json.loads((aside[0] / eval_run.RECORD_NAME).read_text())["config"]["levels"] == [0]
    assert json.loads((out / eval_run.RECORD_NAME).read_text())["config"]["levels"] == [1]
    assert "overwrite" not in json.loads((out / eval_run.RECORD_NAME).read_text())["config"]
    assert "| metric | level 1 | overall |" in Path(second["levels"]).read_text()


def test_unfinished_and_training_folders(tmp_path):
    unfinished = tmp_path / "unfinished"
    (unfinished / "logs").mkdir(parents=True)
    (unfinished / "trajectories.png").write_bytes(b"png")
    (unfinished / "notes.txt").write_text("mine")
    with pytest.raises(RunDirError, match=r"holds the files of an evaluation that did not finish "
                                          r"\(logs, trajectories.png\)"):
        open_eval_dir(unfinished)
    with open_eval_dir(unfinished, overwrite=True):
        pass
    left = sorted(p.name for p in unfinished.iterdir())
    assert left[:2] == ["eval.lock", "notes.txt"] and left[2].startswith("overwritten-") and len(left) == 3
    run = tmp_path / "run"
    run.mkdir()
    (run / "last.pt").write_bytes(b"")
    for overwrite in (False, True):
        with pytest.raises(RunDirError, match=rf"output_dir={run} is a training run's folder \(it holds last.pt\)"):
            open_eval_dir(run, overwrite=overwrite)
    assert os.listdir(run) == ["last.pt"]
