"""recipes/gpu_job.py: a run trained to a deadline, packed into parts a lent machine can return,
unpacked here byte for byte."""

import json
import sys
from pathlib import Path

import pytest

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import gpu_job  # noqa: E402

from legoh_rl.training.checkpoint import load_checkpoint  # noqa: E402


def fake_run(run_dir: Path, size: int) -> bytes:
    run_dir.mkdir(parents=True)
    data = bytes(range(256)) * (size // 256) + b"x" * (size % 256)
    (run_dir / "last.pt").write_bytes(data)
    (run_dir / "metrics.jsonl").write_text('{"step": 1}\n')
    (run_dir / "snapshots").mkdir()
    for frames in (100, 200):
        (run_dir / "snapshots" / f"frames{frames:09d}.pt").write_bytes(b"snap%d" % frames)
    return data


def test_pack_splits_under_the_file_limit_and_unpack_joins_byte_for_byte(tmp_path, monkeypatch):
    monkeypatch.setattr(gpu_job, "PART_BYTES", 1000)
    data = fake_run(tmp_path / "run", 2500)
    manifest = gpu_job.pack(tmp_path / "run", tmp_path / "out")
    assert manifest["last.pt"]["parts"] == ["last.pt.part00", "last.pt.part01", "last.pt.part02"]
    assert [(tmp_path / "out" / p).stat().st_size for p in manifest["last.pt"]["parts"]] == [1000, 1000, 500]
    assert sorted(manifest["files"]) == ["frames000000200.pt", "metrics.jsonl"]  # the newest snapshot only
    (tmp_path / "here").mkdir()
    (tmp_path / "here" / "last.pt").write_bytes(b"older")
    last = gpu_job.unpack(tmp_path / "out", tmp_path / "here")
    assert last.read_bytes() == data and (tmp_path / "here" / "last.pt.before-unpack").read_bytes() == b"older"
    assert (tmp_path / "here" / "snapshots" / "frames000000200.pt").read_bytes() == b"snap200"
    good = (tmp_path / "out" / "manifest.json").read_text()
    # a manifest that would write outside the run folder is refused
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    manifest["files"]["metrics.jsonl"]["to"] = "../../escaped.jsonl"
    (tmp_path / "out" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="leaves the run folder"):
        gpu_job.unpack(tmp_path / "out", tmp_path / "again")
    (tmp_path / "out" / "manifest.json").write_text(good)
    # a damaged or missing part is refused by name
    (tmp_path / "out" / "last.pt.part01").write_bytes(b"\0" * 1000)
    with pytest.raises(ValueError, match="does not match the manifest's SHA-256"):
        gpu_job.unpack(tmp_path / "out", tmp_path / "again")
    (tmp_path / "out" / "last.pt.part01").unlink()
    with pytest.raises(FileNotFoundError, match="last.pt.part01: a part of last.pt is missing"):
        gpu_job.unpack(tmp_path / "out", tmp_path / "again")
    with pytest.raises(FileNotFoundError, match="no manifest"):
        gpu_job.unpack(tmp_path, tmp_path / "again")


def test_a_state_too_big_for_one_call_is_refused_naming_the_fix(tmp_path, monkeypatch):
    monkeypatch.setattr(gpu_job, "PART_BYTES", 100)
    fake_run(tmp_path / "run", 1000)
    with pytest.raises(ValueError, match=r"needs 13 files, more than the 8 .* dagger_replay.capacity"):
        gpu_job.pack(tmp_path / "run", tmp_path / "out")
    with pytest.raises(FileNotFoundError, match="no checkpoint to bring back"):
        gpu_job.pack(tmp_path / "nothing", tmp_path / "out")


def test_train_resumes_the_experiment_then_packs_it(tmp_path):
    run = tmp_path / "st"
    tiny = ["env.num_envs=4", "env.num_threads=1", "env.categories=[randommix]", "env.variants=1",
            "env.category_weights=null", "collector.steps_per_env=10", "collector.total_frames=40",
            "dagger_replay.capacity=100", "dagger_replay.batch_size=8", "dagger_minibatches=2",
            "logger.backend=csv", "checkpoint.snapshot_every=1", f"checkpoint.dir={run}"]
    assert gpu_job.main(["train", "--experiment", "student_h1", "--seconds", "300", "--out", str(tmp_path / "out"),
                         "--", *tiny]) == 0
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["files"]["frames000000040.pt"]["to"] == "snapshots/frames000000040.pt"
    assert gpu_job.main(["unpack", "--files", str(tmp_path / "out"), "--run-dir", str(tmp_path / "back")]) == 0
    state = load_checkpoint(tmp_path / "back" / "last.pt")
    assert state["frames"] == 40 and state["meta"]["experiment"] == "student_h1"
    with pytest.raises(FileNotFoundError, match="no experiment 'nope'"):
        gpu_job.run_dir_of("nope", [])
