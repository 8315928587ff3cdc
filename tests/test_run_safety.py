"""No run is lost or mixed: run-folder ownership, locks, kills at random moments, signals, and
errors that name the file (issue 24)."""

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from legoh_rl.training.checkpoint import (
    RENAMED,
    CheckpointError,
    export_policy,
    file_digest,
    load_checkpoint,
    recorded_checkpoint,
    save_checkpoint,
    warm_start_frames,
)
from legoh_rl.training.logging import MetricsFile, trim_csv_logs
from legoh_rl.training.run_dir import RunDirError, RunDirLock, check_run_dir, open_run_dir

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2", "logger.backend=csv"]
BATCH = 32  # frames per iteration of TINY


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def tiny_run(ck, frames, *extra):
    return oracle_ppo.train(cfg_of("oracle_ppo", TINY + [f"collector.total_frames={frames}", f"checkpoint.dir={ck}",
                                                         *extra]))


def steps(path):
    return [json.loads(line)["step"] for line in Path(path).read_text().splitlines()]


def _holds_lock(ck, pid):
    """Whether process ``pid`` has taken run folder ``ck`` (its pid in ``run.lock``)."""
    try:
        return (ck / "run.lock").read_text().strip() == str(pid)
    except FileNotFoundError:
        return False


def csv_steps(ck, name="reward/total"):
    (path,) = Path(ck, "logs").rglob(f"scalars/{name}.csv")
    return [int(float(line.split(",")[0])) for line in path.read_text().splitlines()]


# -- the folder belongs to one run ---------------------------------------------------------------

def test_fresh_run_refuses_a_folder_with_a_checkpoint_and_overwrite_moves_it_aside(tmp_path):
    ck = tmp_path / "ck"
    tiny_run(ck, 64)
    before = load_checkpoint(ck / "last.pt")
    with pytest.raises(RunDirError, match=r"holds another run's checkpoint .*checkpoint.resume=auto.*"
                                          r"checkpoint.overwrite=true.*another checkpoint.dir"):
        tiny_run(ck, 32)
    assert load_checkpoint(ck / "last.pt")["frames"] == before["frames"] == 64  # untouched
    tiny_run(ck, 32, "checkpoint.overwrite=true")
    assert load_checkpoint(ck / "last.pt")["frames"] == 32 and steps(ck / "metrics.jsonl") == [32]
    (old,) = ck.glob("overwritten-*")
    assert load_checkpoint(old / "last.pt")["frames"] == 64 and steps(old / "metrics.jsonl") == [32, 64]


def test_new_stage_into_a_folder_of_another_run_is_refused(tmp_path):
    tiny_run(tmp_path / "a", 32)
    tiny_run(tmp_path / "b", 32)
    with pytest.raises(RunDirError, match=r"a new stage from .*a/last.pt would overwrite it"):
        tiny_run(tmp_path / "b", 64, f"checkpoint.resume={tmp_path / 'a' / 'last.pt'}")
    check_run_dir(tmp_path / "b", str(tmp_path / "b" / "last.pt"))  # its own checkpoint: fine


def test_second_live_run_is_refused_and_a_dead_runs_lock_is_taken_over(tmp_path):
    with RunDirLock(tmp_path):
        with pytest.raises(RunDirError, match=rf"another run \(pid {os.getpid()}\) is training in {tmp_path}"):
            RunDirLock(tmp_path)
        with pytest.raises(RunDirError, match="another run"):
            tiny_run(tmp_path, 32)
    # a process that died holding the lock: the kernel dropped it, the next run takes it
    dead = subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                           "from legoh_rl.training.run_dir import RunDirLock; RunDirLock(sys.argv[2]); "
                           "import os; os._exit(9)", str(ROOT), str(tmp_path)])
    assert dead.returncode == 9 and (tmp_path / "run.lock").is_file()
    RunDirLock(tmp_path).release()


def test_leftovers_of_a_run_that_never_checkpointed_are_moved_aside(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"step": 32}\n{"step": 64}\n')
    (tmp_path / "last.pt.abc123.tmp").write_bytes(b"partial")
    open_run_dir(tmp_path, "auto").release()
    assert not (tmp_path / "metrics.jsonl").exists() and not list(tmp_path.glob("*.tmp"))
    (moved,) = tmp_path.glob("abandoned-*")
    assert steps(moved / "metrics.jsonl") == [32, 64]


# -- logs hold each step once --------------------------------------------------------------------

def test_torn_last_metrics_line_is_dropped_and_a_bad_middle_line_named(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"step": 32, "a": 1}\n{"step": 64, "a": 2}\n{"step": 96, "a"')
    MetricsFile(path, resume_step=64)
    assert steps(path) == [32, 64]
    path.write_text('{"step": 32}\nnot json\n{"step": 96}\n')
    with pytest.raises(ValueError, match=rf"{path}, line 2, is not a JSON row"):
        MetricsFile(path, resume_step=64)


def test_csv_logs_trimmed_to_the_resumed_step(tmp_path):
    f = tmp_path / "logs" / "run" / "scalars" / "reward" / "total.csv"
    f.parent.mkdir(parents=True)
    f.write_text("32,0.1\n64,0.2\n96,0.3\n128,0.")
    assert trim_csv_logs(tmp_path / "logs", 64) == 2
    assert f.read_text() == "32,0.1\n64,0.2\n"


def test_logs_are_written_with_the_checkpoint_only(tmp_path):
    """Rows after the last checkpoint are not logged: a kill there loses nothing a resume redoes."""
    tiny_run(tmp_path, 128, "checkpoint.every=3")  # checkpoints at iterations 3 and 4 (the end)
    assert steps(tmp_path / "metrics.jsonl") == [32, 64, 96, 128] == csv_steps(tmp_path)


def test_killed_at_random_moments_resume_logs_each_step_once(tmp_path):
    """kill -9 real training processes at random times, resume each time: every invariant holds."""
    rng = random.Random(0)
    ck = tmp_path / "ck"
    total = 30 * BATCH
    cmd = [sys.executable, str(RECIPES / "oracle_ppo.py"), *TINY, f"collector.total_frames={total}",
           f"checkpoint.dir={ck}", "checkpoint.every=2", "checkpoint.resume=auto"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for _ in range(3):
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # Each kill lands in the run, not in its imports (~5 s, waited out: the process writes its
        # pid into run.lock once it has taken the folder), at a random moment: some before a
        # checkpoint, some while one is written, some after.
        deadline = time.time() + 120
        while proc.poll() is None and time.time() < deadline and not _holds_lock(ck, proc.pid):
            time.sleep(0.1)
        time.sleep(rng.uniform(0.3, 2.5))  # the 30 iterations take ~4 s after the lock
        proc.kill()
        proc.wait()
        if (ck / "last.pt").is_file():
            state = load_checkpoint(ck / "last.pt")  # never torn
            if (ck / "metrics.jsonl").is_file():  # logs never run ahead of the checkpoint
                assert steps(ck / "metrics.jsonl")[-1] <= state["frames"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    expected = list(range(BATCH, total + 1, BATCH))
    assert steps(ck / "metrics.jsonl") == expected
    assert csv_steps(ck) == expected
    assert load_checkpoint(ck / "last.pt")["frames"] == total
    assert not list(ck.glob("*.tmp"))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_writes_a_final_checkpoint_and_exits_nonzero(tmp_path, sig):
    ck = tmp_path / "ck"
    cmd = [sys.executable, str(RECIPES / "oracle_ppo.py"), *TINY, "collector.total_frames=100000",
           f"checkpoint.dir={ck}", "checkpoint.every=1000"]
    proc = subprocess.Popen(cmd, env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 120
    while not (ck / "logs").exists() and time.time() < deadline:  # training started
        time.sleep(0.5)
    time.sleep(2.0)
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, out[-2000:]
    state = load_checkpoint(ck / "last.pt")  # checkpoint.every=1000: written because of the signal
    assert state["frames"] > 0 and steps(ck / "metrics.jsonl")[-1] == state["frames"]
    assert "stopping after this iteration" in out


# -- errors name the file ------------------------------------------------------------------------

@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 truncated zip", b"\x80\x04garbage"])
def test_unreadable_checkpoints_name_the_file(tmp_path, content):
    bad = tmp_path / "last.pt"
    bad.write_bytes(content)
    with pytest.raises(CheckpointError, match=rf"{bad} \({len(content)} bytes\) is not a readable checkpoint"):
        load_checkpoint(bad)
    with pytest.raises(CheckpointError, match=rf"{bad}"):
        tiny_run(tmp_path, 64, "checkpoint.resume=auto")
    torch.save({"weights": 1}, bad)
    with pytest.raises(CheckpointError, match=rf"{bad} is not a legoh-rl checkpoint"):
        load_checkpoint(bad)


def test_resume_from_a_policy_export_says_to_use_init(tmp_path):
    tiny_run(tmp_path / "a", 32)
    slim = export_policy(tmp_path / "a" / "last.pt", tmp_path / "policy.pt")
    with pytest.raises(CheckpointError, match=rf"{slim} holds no training state.*checkpoint.init={slim}"):
        tiny_run(tmp_path / "b", 64, f"checkpoint.resume={slim}")


def test_resume_with_other_layers_names_model_layers(tmp_path):
    tiny_run(tmp_path, 32, "model.layers=[32,32]")
    with pytest.raises(CheckpointError, match=r"set model.layers=\[32, 32\] to resume it \(this run has "
                                              r"model.layers=\[64, 64\]\)"):
        tiny_run(tmp_path, 64, "model.layers=[64,64]", "checkpoint.resume=auto")


@pytest.mark.parametrize("override,message", [
    ("env.num_envs=2.5", r"env.num_envs must be a positive integer, got 2.5"),
    ("torch_threads=0", r"torch_threads must be a positive integer, got 0"),
    ("model.layers=[]", r"model.layers must be a non-empty list of positive integers .*got \[\]"),
    ("model.layers=[64,-1]", r"got \[64, -1\]"),
])
def test_config_values_checked_before_work(tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        tiny_run(tmp_path, 32, override)
    assert not (tmp_path / "metrics.jsonl").exists()


def test_student_resume_under_another_teacher_is_refused(tmp_path):
    env = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1", "logger.backend=csv"]
    for name, seed in (("t1", 0), ("t2", 1)):
        oracle_ppo.train(cfg_of("oracle_ppo", env + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                     "ppo.num_epochs=1", f"env.seed={seed}",
                                                     f"checkpoint.dir={tmp_path / name}"]))

    def student(teacher, *extra):
        return cfg_of("unified", env + [f"teacher={tmp_path / teacher / 'last.pt'}", "collector.steps_per_env=10",
                                        "dagger_iters=1", "ppo.num_epochs=1", f"checkpoint.dir={tmp_path / 's'}",
                                        *extra])

    unified.train(student("t1", "collector.total_frames=40"))
    with pytest.raises(CheckpointError, match=r"was distilled from teacher .*t1/last.pt.*allow_new_teacher=true"):
        unified.build(student("t2", "collector.total_frames=80", "checkpoint.resume=auto"))
    p = unified.build(student("t2", "collector.total_frames=80", "checkpoint.resume=auto", "allow_new_teacher=true"))
    assert p.frames == 40
    assert unified.build(student("t1", "collector.total_frames=80", "checkpoint.resume=auto")).frames == 40
    # the teacher's file renamed: found by its digest, named in the refusal, and resumable under its new name
    export_policy(tmp_path / "s" / "last.pt", tmp_path / "slim.pt")
    assert load_checkpoint(tmp_path / "slim.pt")["meta"]["teacher_sha256"] == file_digest(tmp_path / "t1" / "last.pt")
    (tmp_path / "t1" / "last.pt").rename(tmp_path / "t1" / "moved.pt")
    with pytest.raises(CheckpointError, match=r"t1/last.pt \(now .*t1/moved.pt\).*pass teacher=.*t1/moved.pt to continue"):
        unified.build(student("t2", "collector.total_frames=80", "checkpoint.resume=auto"))
    p = unified.build(cfg_of("unified", env + [f"teacher={tmp_path / 't1' / 'moved.pt'}", "collector.steps_per_env=10",
                                               "dagger_iters=1", "ppo.num_epochs=1", f"checkpoint.dir={tmp_path / 's'}",
                                               "collector.total_frames=80", "checkpoint.resume=auto"]))
    assert p.frames == 40


def test_warm_start_frames_add_up_the_chain_of_initialisations(tmp_path):
    """A student initialised from B, itself initialised from A, has had A's and B's recorded env
    steps of training behind its own: 100 + 50. B is found by its digest after a rename; where a
    link's file is gone or changed, the chain stops at that link's recorded frames; a loop is
    refused."""
    def link(name, frames, init=None):
        meta = {"initialised_from": {"checkpoint": init, "sha256": file_digest(tmp_path / init),
                                     "frames": load_checkpoint(tmp_path / init)["frames"]}} if init else {}
        save_checkpoint(tmp_path / name, {"meta": meta, "frames": frames})
        return load_checkpoint(tmp_path / name)["meta"]

    link("a.pt", 100)
    link("b.pt", 50, "a.pt")
    c = {"initialised_from": {"checkpoint": "b.pt", "sha256": file_digest(tmp_path / "b.pt"), "frames": 50}}
    assert warm_start_frames({}, tmp_path) == 0
    assert warm_start_frames(load_checkpoint(tmp_path / "b.pt")["meta"], tmp_path) == 100
    assert warm_start_frames(c, tmp_path) == 150
    (tmp_path / "b.pt").rename(tmp_path / "b_renamed.pt")  # found by its digest beside the recorded name
    assert warm_start_frames(c, tmp_path) == 150
    (tmp_path / "a.pt").unlink()  # the chain stops at b's record of a: a lower bound
    assert warm_start_frames(c, tmp_path) == 150
    (tmp_path / "b_renamed.pt").unlink()
    assert warm_start_frames(c, tmp_path) == 50
    loop = {"initialised_from": {"checkpoint": "loop.pt", "sha256": None, "frames": 1}}
    save_checkpoint(tmp_path / "loop.pt", {"meta": loop, "frames": 1})
    with pytest.raises(CheckpointError, match="'loop.pt' is longer than 16 links"):
        warm_start_frames(loop, tmp_path)


def test_recorded_checkpoint_follows_renames_by_digest_or_the_registry(tmp_path, monkeypatch):
    """A path a run recorded means the file it held then: with the recorded digest, the file holding
    those bytes (the same path, the RENAMED entry, a sibling); without one, RENAMED's name today."""
    root = Path(__file__).resolve().parents[1]
    for new, digest in RENAMED.values():
        assert file_digest(root / new) == digest  # the registry names the files' true bytes
    old, (new, digest) = next(iter(RENAMED.items()))
    assert recorded_checkpoint(old) == new  # records older than the rename hold no digest
    assert recorded_checkpoint(old, digest, root) == new
    assert recorded_checkpoint(old, file_digest(root / old), root) == old  # a record made after it
    (tmp_path / "a.pt").write_bytes(b"a")
    (tmp_path / "b.pt").write_bytes(b"b")
    assert recorded_checkpoint(str(tmp_path / "a.pt"), file_digest(tmp_path / "b.pt")) == str(tmp_path / "b.pt")
    rel = f"{tmp_path.name}/a.pt"  # relative to root: the answer stays relative
    assert recorded_checkpoint(rel, file_digest(tmp_path / "b.pt"), tmp_path.parent) == f"{tmp_path.name}/b.pt"
    assert recorded_checkpoint("ck/a.pt", file_digest(tmp_path / "b.pt"), tmp_path) == "ck/a.pt"  # no such folder
    assert recorded_checkpoint(str(tmp_path / "a.pt"), "0" * 64) == str(tmp_path / "a.pt")  # nowhere: as recorded
    assert recorded_checkpoint("elsewhere/x.pt") == "elsewhere/x.pt"
    # the stage-4 H1 oracle, oracle_h1.pt from 2026-12-04 to 12-05, is found by its digest beside the name
    stage4 = "42d583151a3c75e7648b0f8e715db6da0eb400d820a6398f69f40c5fe2bfcdce"
    assert recorded_checkpoint("checkpoints/oracle_h1.pt", stage4, root) == "checkpoints/oracle_h1_foot_scan.pt"
    # a teacher path that no longer holds a file names where the registry says it went
    monkeypatch.setitem(RENAMED, "checkpoints/oracle_h1_gone.pt", ("checkpoints/oracle_h1_clocked.pt", "0" * 64))
    with pytest.raises(FileNotFoundError, match=r"no checkpoint at checkpoints/oracle_h1_gone.pt "
                                                r"\(renamed: teacher=checkpoints/oracle_h1_clocked.pt\)"):
        unified.validate(cfg_of("unified", ["teacher=checkpoints/oracle_h1_gone.pt"]))


def test_bad_action_total_survives_a_resume(tmp_path):
    parts = oracle_ppo.build(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={tmp_path}"]))
    parts.env.bad_action_total = 7
    state = parts.env.state_dict()
    parts.env.bad_action_total = 0
    parts.env.load_state_dict(state)
    assert parts.env.bad_action_total == 7


def test_env_takes_bfloat16_actions_and_names_a_missing_action():
    from scenes import BoxScene
    from tensordict import TensorDict

    from legoh_rl.envs import HikingEnv, HikingEnvConfig

    env = HikingEnv(HikingEnvConfig(num_envs=2, num_threads=1), trails=BoxScene())
    env.reset()
    a = torch.full((2, env.A), 0.1)
    nxt = env.step(TensorDict({"action": a.to(torch.bfloat16)}, batch_size=[2]))["next"]
    assert torch.isfinite(nxt["proprio"]).all()
    np.testing.assert_allclose(env.step_state.action, np.full((2, env.A), float(torch.tensor(0.1).to(torch.bfloat16))))
    with pytest.raises(KeyError, match=r"needs an 'action' entry of shape \(2, 10\)"):
        env.step(TensorDict({"other": a}, batch_size=[2]))
