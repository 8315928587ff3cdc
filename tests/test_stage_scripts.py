"""The staged training scripts (recipes/*_stages.sh) run their stages in order, each resuming the
last one, with overrides that the recipe's config accepts. A dry run: ``python`` is replaced by a
shell stand-in that records its arguments; each stage's config is then composed and its env
section and reward weights validated here (nothing is built or trained)."""

import os
import subprocess
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from legoh_rl.envs.rewards import reward_weights
from legoh_rl.envs.robots import get_robot_spec
from legoh_rl.training.builders import env_config

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "recipes").glob("*_stages.sh"))
FAKE_PYTHON = """#!/bin/sh
printf '%s\\037' "$@" >> "$STAGE_LOG"
printf '\\036' >> "$STAGE_LOG"
"""


def dry_run(script: Path, tmp_path: Path, extra_env: dict | None = None) -> list[dict]:
    """Run ``script`` with the stand-in ``python``: one {"recipe", "overrides"} per call, in order."""
    fake = tmp_path / "python"
    fake.write_text(FAKE_PYTHON)
    fake.chmod(0o755)
    log = tmp_path / "calls"
    env = {**os.environ, "PYTHON": str(fake), "STAGE_LOG": str(log), **(extra_env or {})}
    subprocess.run(["bash", str(script), str(tmp_path / "out")], check=True, env=env, capture_output=True, text=True)
    calls = []
    for record in log.read_text().split("\036")[:-1]:
        args = record.split("\037")[:-1]
        calls.append({"recipe": Path(args[0]).stem, "overrides": args[1:]})
    return calls


def validate_oracle_stage(overrides: list[str]) -> None:
    """Compose oracle_ppo's config with ``overrides`` and validate its env section and rewards."""
    with initialize_config_dir(config_dir=str(ROOT / "recipes" / "config"), version_base=None):
        cfg = compose(config_name="oracle_ppo", overrides=overrides)
    env = env_config(cfg.env, mode="oracle")
    reward_weights(get_robot_spec(env.robot).reward_weights, env.reward_overrides, student=False)


def value(overrides: list[str], key: str) -> str | None:
    hits = [o.split("=", 1)[1] for o in overrides if o.split("=", 1)[0] == key]
    return hits[-1] if hits else None


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.name for s in SCRIPTS])
def test_stages_chain_and_their_configs_validate(script, tmp_path):
    assert len(SCRIPTS) >= 3
    calls = dry_run(script, tmp_path)
    stages, export = calls[:-1], calls[-1]
    assert len(stages) >= 2 and all(c["recipe"] == "oracle_ppo" for c in stages)
    out = tmp_path / "out"
    totals = [int(value(c["overrides"], "collector.total_frames")) for c in stages]
    assert totals == sorted(totals) and len(set(totals)) == len(totals), totals
    for n, call in enumerate(stages, start=1):
        validate_oracle_stage(call["overrides"])
        assert value(call["overrides"], "checkpoint.dir") == f"{out}/stage{n}"
        resume = value(call["overrides"], "checkpoint.resume")
        assert resume == (None if n == 1 else f"{out}/stage{n - 1}/last.pt")
    assert export["recipe"] == "export_policy" and export["overrides"][0] == f"{out}/stage{len(stages)}/last.pt"


def test_from_stage_skips_the_finished_stages(tmp_path):
    script = ROOT / "recipes" / "oracle_h1_stages.sh"
    calls = dry_run(script, tmp_path, {"FROM_STAGE": "5"})
    assert [value(c["overrides"], "checkpoint.dir").rsplit("/", 1)[1] for c in calls[:-1]] == ["stage5", "stage6"]


def test_an_interrupted_stage_resumes_its_own_checkpoint(tmp_path):
    """Running a script again after an interruption: stages with a checkpoint go on from it."""
    script = ROOT / "recipes" / "oracle_h1_stages.sh"
    out = tmp_path / "out"
    for n in (1, 2, 3):
        (out / f"stage{n}").mkdir(parents=True)
        (out / f"stage{n}" / "last.pt").write_bytes(b"")
    calls = dry_run(script, tmp_path)[:-1]
    resumes = [value(c["overrides"], "checkpoint.resume") for c in calls]
    assert resumes[:3] == [f"{out}/stage{n}/last.pt" for n in (1, 2, 3)]
    assert resumes[3] == f"{out}/stage3/last.pt"  # stage 4 starts from the end of stage 3


def test_clock_stage3_keeps_the_curriculum_when_asked(tmp_path):
    """STAGE3_CURRICULUM=1 (run 14): stage 3 goes on from stage 2's levels with the curriculum on."""
    script = ROOT / "recipes" / "oracle_h1_clock_stages.sh"
    default = dry_run(script, tmp_path, {"FROM_STAGE": "3"})[0]["overrides"]
    assert value(default, "env.curriculum") == "false" and value(default, "checkpoint.keep_curriculum") == "false"
    assert value(default, "env.levels") == "[0,1]" and value(default, "ppo.desired_kl") == "0.02"
    (tmp_path / "calls").unlink()
    kept = dry_run(script, tmp_path, {"FROM_STAGE": "3", "STAGE3_CURRICULUM": "1"})[0]["overrides"]
    assert value(kept, "env.curriculum") == "true" and value(kept, "checkpoint.keep_curriculum") == "true"
    assert value(kept, "env.levels") is None and value(kept, "ppo.desired_kl") == "0.01"
    assert value(kept, "model.max_std") == "0.5" and value(kept, "checkpoint.dir").endswith("/stage3")
    validate_oracle_stage(kept)


def test_clock_stages_take_the_robot_from_ROBOT(tmp_path):
    """ROBOT=g1 (G1 run 2) puts env.robot=g1 in every stage and names the export oracle_g1.pt;
    the default stays H1."""
    script = ROOT / "recipes" / "oracle_h1_clock_stages.sh"
    default = dry_run(script, tmp_path)
    assert [value(c["overrides"], "env.robot") for c in default[:3]] == ["h1"] * 3
    assert default[3]["overrides"][-1].endswith("/oracle_h1.pt")
    (tmp_path / "calls").unlink()
    g1 = dry_run(script, tmp_path, {"ROBOT": "g1", "FEEDFORWARD": "1", "STAGE3_CURRICULUM": "1"})
    assert [c["recipe"] for c in g1] == ["oracle_ppo"] * 3 + ["export_policy"]
    for call in g1[:3]:
        assert value(call["overrides"], "env.robot") == "g1"
        assert value(call["overrides"], "env.gait_feedforward") == "1"
        validate_oracle_stage(call["overrides"])
    assert g1[3]["overrides"] == [f"{tmp_path}/out/stage3/last.pt", f"{tmp_path}/out/oracle_g1.pt"]


def test_clock_stages_take_the_swing_amplitude_from_AMPLITUDE(tmp_path):
    """AMPLITUDE=0.45 (G1 run 3) sets env.gait_amplitude in every stage; the default is 0.25 (runs 13-14)."""
    script = ROOT / "recipes" / "oracle_h1_clock_stages.sh"
    default = dry_run(script, tmp_path)
    assert [value(c["overrides"], "env.gait_amplitude") for c in default[:3]] == ["0.25"] * 3
    (tmp_path / "calls").unlink()
    wide = dry_run(script, tmp_path, {"ROBOT": "g1", "AMPLITUDE": "0.45", "FEEDFORWARD": "1"})
    for call in wide[:3]:
        assert value(call["overrides"], "env.gait_amplitude") == "0.45"
        validate_oracle_stage(call["overrides"])
