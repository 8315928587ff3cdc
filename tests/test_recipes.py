"""Recipes end to end on tiny configs (issue 8): training, resume, evaluation, bad configs.

Why one file of ~700 lines: each test runs a recipe as its command line does, on the same tiny
configs and helpers; the recipes with many tests of their own have their own files
(``test_unified.py``, ``test_paper_tables.py``, ``test_eval_folder.py``, ...)."""

import json
import math
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from legoh_rl.training.checkpoint import load_checkpoint, save_checkpoint
from legoh_rl.training.config_store import env_config
from legoh_rl.training.evaluation import aggregate, markdown_table
from legoh_rl.training.schedules import FeedforwardSchedule

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
ROOT = RECIPES.parent
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402

from legoh_rl.training import eval_run  # noqa: E402

TINY = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1",
        "collector.steps_per_env=8", "ppo.num_epochs=1", "ppo.num_minibatches=2", "logger.backend=csv"]


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def test_oracle_trains_then_resumes_where_it_stopped(tmp_path):
    ck = tmp_path / "ck"
    first = oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=64", f"checkpoint.dir={ck}",
                                                          "checkpoint.every=1"]))
    assert first["iteration"] == 2 and first["frames"] == 64
    saved = load_checkpoint(ck / "last.pt")
    assert saved["iteration"] == 2 and saved["meta"]["robot"] == "h1"
    assert any((ck / "logs").rglob("*.csv"))
    import plot_curves

    rows = plot_curves.load(ck / "metrics.jsonl")
    assert [r["step"] for r in rows] == [32, 64] and "reward/total" in rows[0]
    for r in rows:  # where each iteration's env time went: its steps, their physics, its resets
        assert 0 < r["env/physics_s"] < r["env/step_s"] < r["train/collect_s"] and r["env/reset_s"] >= 0
    assert plot_curves.plot(rows, tmp_path / "curves.png", "tiny").stat().st_size > 1000
    gait = plot_curves.plot(rows, tmp_path / "gait.png", "tiny", panels=plot_curves.GAIT_PANELS)
    assert gait.stat().st_size > 1000 and all(len(p) == 6 for p in plot_curves.PANEL_SETS.values())
    # "interrupted": continue the same run to 96 frames; state restored exactly first
    cfg = cfg_of("oracle_ppo", TINY + ["collector.total_frames=96", f"checkpoint.dir={ck}", "checkpoint.resume=auto"])
    parts = oracle_ppo.build(cfg)
    assert parts.iteration == 2 and parts.frames == 64
    for k, v in saved["loss"].items():
        assert torch.equal(parts.loss.state_dict()[k], v), k
    assert (parts.env.curriculum.levels == saved["env"]["curriculum"]["levels"]).all()
    second = oracle_ppo.train(cfg, env=parts.env)
    assert second["iteration"] == 3 and second["frames"] == 96
    assert load_checkpoint(ck / "last.pt")["iteration"] == 3


def test_resume_as_a_new_stage_takes_the_configs_coefficients_and_levels(tmp_path):
    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}"]))
    saved = load_checkpoint(ck / "last.pt")
    saved["env"]["curriculum"]["levels"][:] = 3  # as if the curriculum had moved every world up
    torch.save(saved, ck / "last.pt")
    stage = ["collector.total_frames=64", f"checkpoint.dir={ck}", "checkpoint.resume=auto", "ppo.entropy_coeff=0.002",
             "ppo.clip_epsilon=0.1", "env.levels=[1]"]
    same = oracle_ppo.build(cfg_of("oracle_ppo", TINY + stage))
    assert (same.env.curriculum.levels == 3).all()  # default: the curriculum state is kept
    new = oracle_ppo.build(cfg_of("oracle_ppo", TINY + stage + ["checkpoint.keep_curriculum=false"]))
    assert (new.env.curriculum.levels == 1).all()
    for parts in (same, new):  # the loss buffers take the config's values, not the checkpoint's 0.01 / 0.2
        assert parts.loss.entropy_coeff.item() == pytest.approx(0.002)
        assert parts.loss.clip_epsilon.item() == pytest.approx(0.1)
        assert parts.iteration == 1 and parts.frames == 32


@pytest.mark.parametrize("override,message", [
    ("env.robot=atlas", r"unknown robot 'atlas'"),
    ("env.categories=[swamp]", r"unknown trail category 'swamp'"),
    ("env.num_envs=0", r"env.num_envs must be a positive integer, got 0"),
    ("collector.total_frames=0", r"collector.total_frames must be a positive integer, got 0"),
    ("checkpoint.resume=/nonexistent/last.pt", r"no checkpoint at /nonexistent/last.pt"),
    ("update_threads=0", r"update_threads must be a positive integer, got 0"),
])
def test_bad_config_values_refused(override, message, tmp_path):
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        oracle_ppo.train(cfg_of("oracle_ppo", TINY + [override, f"checkpoint.dir={tmp_path}"]))


def test_ppo_update_runs_on_update_threads(tmp_path, monkeypatch):
    """Collection keeps torch_threads; the update (physics idle) runs on update_threads."""
    seen = []
    real = oracle_ppo.ppo_update

    def spy(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(oracle_ppo, "ppo_update", spy)
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=64", "update_threads=2",
                                                  f"checkpoint.dir={tmp_path}"]))
    assert seen == [2, 2] and torch.get_num_threads() == 1


def test_checkpoint_for_another_robot_refused(tmp_path):
    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}"]))
    cfg = cfg_of("oracle_ppo", TINY + ["env.robot=g1", "collector.total_frames=64", f"checkpoint.dir={ck}",
                                       "checkpoint.resume=auto"])
    with pytest.raises(ValueError, match=r"robot: checkpoint has 'h1', this run needs 'g1'"):
        oracle_ppo.build(cfg)


def test_aggregate_matches_hand_computed_values():
    eps = [
        # run 0: randommix one success (T2R 5 s) one fall; gap one fall
        {"run": 0, "category": "randommix", "level": 0, "success": 100.0, "trail_completion": 100.0,
         "traverse_rate": 100.0, "mev": 2.0, "ttf": 5.0, "time_to_reach": 5.0},
        {"run": 0, "category": "randommix", "level": 1, "success": 0.0, "trail_completion": 50.0,
         "traverse_rate": 40.0, "mev": 4.0, "ttf": 3.0, "time_to_reach": math.nan},
        {"run": 0, "category": "gap", "level": 0, "success": 0.0, "trail_completion": 0.0,
         "traverse_rate": 10.0, "mev": 6.0, "ttf": 1.0, "time_to_reach": math.nan},
        # run 1: randommix two successes
        {"run": 1, "category": "randommix", "level": 0, "success": 100.0, "trail_completion": 100.0,
         "traverse_rate": 100.0, "mev": 0.0, "ttf": 7.0, "time_to_reach": 7.0},
        {"run": 1, "category": "randommix", "level": 1, "success": 100.0, "trail_completion": 100.0,
         "traverse_rate": 100.0, "mev": 0.0, "ttf": 9.0, "time_to_reach": 9.0},
    ]
    rows = aggregate(eps)
    # randommix SR per run: 50, 100 -> mean 75, std 25
    assert rows["randommix"]["success"] == pytest.approx((75.0, 25.0))
    # T2R over successes: run 0 -> 5, run 1 -> 8 -> 6.5 +- 1.5
    assert rows["randommix"]["time_to_reach"] == pytest.approx((6.5, 1.5))
    # gap only in run 0, never succeeded: T2R undefined
    assert math.isnan(rows["gap"]["time_to_reach"][0])
    assert rows["gap"]["ttf"] == pytest.approx((1.0, 0.0))
    # overall SR: run 0 = 1/3 -> 33.33, run 1 = 100 -> mean 66.67, std 33.33
    assert rows["overall"]["success"] == pytest.approx((200 / 3, 100 / 3))
    table = markdown_table(rows)
    assert "| Success Rate (%) | 0.00 ± 0.00 | 75.00 ± 25.00 | 66.67 ± 33.33 |" in table
    # by level: level 0 SR per run: run 0 (randommix 100, gap 0) 50, run 1 100; level 1: 0, 100
    levels = aggregate(eps, by="level")
    assert list(levels) == ["level 0", "level 1", "overall"]
    assert levels["level 0"]["success"] == pytest.approx((75.0, 25.0))
    assert levels["level 1"]["success"] == pytest.approx((50.0, 50.0))
    assert levels["level 1"]["ttf"] == pytest.approx((6.0, 3.0))
    assert levels["overall"] == rows["overall"]
    with pytest.raises(ValueError, match="by must be 'category' or 'level', got 'run'"):
        aggregate(eps, by="run")


def test_evaluate_zero_policy_writes_artefacts(tmp_path):
    cfg = cfg_of("evaluate", ["checkpoint=zero", "categories=[randommix]", "levels=[0]", "robots_per_cell=2",
                              "variants=1", "num_threads=1", f"output_dir={tmp_path}", "video_seconds=0.5",
                              "logger.backend=csv"])
    out = eval_run.evaluate(cfg)
    assert len(out["episodes"]) == 2
    overall = out["rows"]["overall"]
    assert overall["success"][0] == 0.0 and math.isnan(overall["time_to_reach"][0])
    assert 0.5 < overall["ttf"][0] < 4.0  # a PD hold falls within a few seconds (docs/physics.md)
    assert "| metric | level 0 | overall |" in Path(out["levels"]).read_text()
    for key in ("table", "levels", "csv", "plot"):
        assert Path(out[key]).is_file()
    if out["video"] is not None:  # needs an OpenGL context (EGL/OSMesa)
        assert Path(out["video"]).stat().st_size > 1000


def test_evaluate_pools_trail_sets_as_runs(tmp_path, monkeypatch):
    """trail_seeds=[0,1]: the protocol on two trail grids (built with those seeds), each one run
    of the tables' mean +- std."""
    seeds, tiles = [], []
    real = eval_run.load_policy

    def spy(*args, **kwargs):
        env, policy, kind = real(*args, **kwargs)
        seeds.append(kwargs["seed"])
        tiles.append(env.trails.tile_end.copy())
        return env, policy, kind

    monkeypatch.setattr(eval_run, "load_policy", spy)
    base = ["checkpoint=zero", "categories=[randommix]", "levels=[1]", "robots_per_cell=2", "variants=1",
            "num_threads=1", "video=false", "logger.backend=csv"]
    out = eval_run.evaluate(cfg_of("evaluate", base + ["trail_seeds=[0,1]", f"output_dir={tmp_path}"]))
    assert seeds == [0, 1] and not np.allclose(tiles[0], tiles[1])  # two different trail grids
    assert [(e["run"], e["trail_seed"]) for e in out["episodes"]] == [(0, 0), (0, 0), (1, 1), (1, 1)]
    ttf = [np.mean([e["ttf"] for e in out["episodes"] if e["run"] == r]) for r in (0, 1)]
    assert out["rows"]["overall"]["ttf"] == pytest.approx((np.mean(ttf), np.std(ttf)))
    with pytest.raises(ValueError, match=r"trail_seeds must be a non-empty list of distinct seeds, got \[3, 3\]"):
        eval_run.evaluate(cfg_of("evaluate", base + ["trail_seeds=[3,3]", f"output_dir={tmp_path}"]))


def test_evaluate_under_domain_randomisation_is_recorded_as_such(tmp_path, monkeypatch):
    """domain_rand=true: the benchmark's env draws the training's randomisation, and the record
    says so; domain_rand=[terms] those terms alone; the default leaves the key out, as the records
    written before it existed."""
    envs = []
    real = eval_run.load_policy

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        envs.append(out[0])
        return out

    monkeypatch.setattr(eval_run, "load_policy", spy)
    base = ["checkpoint=zero", "categories=[randommix]", "levels=[0]", "robots_per_cell=2", "variants=1",
            "num_threads=1", "video=false", "logger.backend=csv"]
    for rand in ("false", "true", "[friction]"):
        out_dir = tmp_path / rand.strip("[]")
        eval_run.evaluate(cfg_of("evaluate", base + [f"domain_rand={rand}", f"output_dir={out_dir}"]))
        record = json.loads((out_dir / eval_run.RECORD_NAME).read_text())["config"]
        randomizer = envs[-1].randomizer
        if rand == "true":
            assert record["domain_rand"] is True and np.unique(randomizer.friction).size == 2 and randomizer.cfg.push
        elif rand == "false":
            assert "domain_rand" not in record and np.all(randomizer.friction == randomizer.nominal_friction)
        else:  # the friction draws alone
            assert record["domain_rand"] == ["friction"] and np.unique(randomizer.friction).size == 2
            assert not randomizer.cfg.push and not randomizer.mass_offset.any()
    for bad, message in (("yes", "domain_rand must be true, false or a non-empty list of terms .*, got 'yes'"),
                         ("[]", "domain_rand must be true, false or a non-empty list"),
                         ("[push,wind]", r"unknown domain randomisation term\(s\) \['wind'\]"),
                         ("[push,push]", r"domain_rand terms must be distinct, got \['push', 'push'\]")):
        with pytest.raises(ValueError, match=message):
            eval_run.evaluate(cfg_of("evaluate", base + [f"domain_rand={bad}", f"output_dir={tmp_path}"]))


def test_exported_policy_is_slim_and_evaluates(tmp_path):
    from legoh_rl.training.checkpoint import export_policy

    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}"]))
    slim = export_policy(ck / "last.pt", tmp_path / "oracle.pt")
    state = load_checkpoint(slim)
    assert "optim" not in state and "env" not in state and state["meta"]["kind"] == "oracle"
    assert slim.stat().st_size < (ck / "last.pt").stat().st_size / 2
    cfg = cfg_of("evaluate", [f"checkpoint={slim}", "categories=[randommix]", "levels=[0]", "robots_per_cell=1",
                              "variants=1", "num_threads=1", f"output_dir={tmp_path / 'e'}", "video=false",
                              "logger.backend=csv"])
    assert len(eval_run.evaluate(cfg)["episodes"]) == 1


def test_evaluate_refuses_a_zero_length_video_before_evaluating(tmp_path, monkeypatch):
    called = []
    monkeypatch.setattr(eval_run, "load_policy", lambda *a, **k: called.append(1))
    cfg = cfg_of("evaluate", ["checkpoint=zero", f"output_dir={tmp_path}", "video_seconds=0", "logger.backend=csv"])
    with pytest.raises(ValueError, match=r"video_seconds must be positive \(or video=false for no video\), got 0"):
        eval_run.evaluate(cfg)
    assert not called  # refused up front, not after the whole evaluation
    from legoh_rl.training.evaluation import render_video

    with pytest.raises(ValueError, match="video seconds must be positive, got 0"):
        render_video(None, None, tmp_path / "v.mp4", seconds=0)


def test_evaluate_missing_checkpoint(tmp_path):
    cfg = cfg_of("evaluate", ["checkpoint=/nonexistent.pt", f"output_dir={tmp_path}", "logger.backend=csv"])
    with pytest.raises(FileNotFoundError, match="checkpoint not found: /nonexistent.pt"):
        eval_run.evaluate(cfg)


def test_plot_curves_joins_resumed_stages_and_smooths():
    import plot_curves

    first = [{"step": s, "reward/total": 1.0} for s in (10, 20, 30, 40)]
    second = [{"step": s, "reward/total": 2.0} for s in (30, 40, 50)]  # resumed from the step-20 checkpoint
    rows, starts = plot_curves.join_stages([first, second])
    assert [r["step"] for r in rows] == [10, 20, 30, 40, 50] and starts == [30]
    assert [r["reward/total"] for r in rows] == [1.0, 1.0, 2.0, 2.0, 2.0]
    assert plot_curves.running_mean([1.0, 3.0, 5.0, 7.0], 2) == [1.0, 2.0, 4.0, 6.0]


def test_plot_curves_draws_every_panel_of_joined_stages(tmp_path, monkeypatch):
    """Every panel after the first still reads its x values from the rows when stage starts are
    marked (a marker once took the x key's place: KeyError on the second panel)."""
    import plot_curves

    figs = []
    monkeypatch.setattr(plot_curves.plt, "close", figs.append)
    first = [{"step": s, "curriculum/gap": 1.0, "episode/gap/success": 20.0} for s in (10, 20, 30)]
    second = [{"step": s, "curriculum/gap": 2.0, "episode/gap/success": 40.0} for s in (30, 40)]
    rows, starts = plot_curves.join_stages([first, second])
    plot_curves.plot(rows, tmp_path / "joined.png", "two stages", starts, panels=plot_curves.TRAIL_PANELS)
    drawn = [ax for ax in figs[0].axes if any(len(line.get_xdata()) == 4 for line in ax.lines)]
    assert len(drawn) >= 2  # the curriculum panel and the grouped-success panel, both on steps 10-40
    assert all(list(ax.lines[0].get_xdata()) == [10, 20, 30, 40] for ax in drawn)


def test_plot_curves_overlays_separate_runs(tmp_path, monkeypatch):
    """--compare: {label: rows} draws each run in its own colour with a legend; NaN values are skipped."""
    import plot_curves

    figs = []
    monkeypatch.setattr(plot_curves.plt, "close", figs.append)
    a = [{"step": s, "loss/im_action": 0.1, "episode/success": float("nan")} for s in (10, 20)]
    b = [{"step": s, "loss/im_action": 0.05, "episode/success": 40.0} for s in (10, 20, 30)]
    out = plot_curves.plot({"a": a, "b": b}, tmp_path / "cmp.png", "two", panels=plot_curves.STUDENT_PANELS)
    assert out.stat().st_size > 1000
    ax_im, ax_sr = figs[0].axes[0], figs[0].axes[3]
    assert ax_im.get_legend_handles_labels()[1] == ["a", "b"]
    assert [list(line.get_ydata()) for line in ax_im.lines] == [[0.1, 0.1], [0.05, 0.05, 0.05]]
    assert [list(line.get_ydata()) for line in ax_sr.lines] == [[40.0, 40.0, 40.0]]  # run a has no values


def test_plot_curves_aligns_runs_at_their_ppo_phase(tmp_path, monkeypatch, capsys):
    """--align ppo: each run's steps count from the first batch of its PPO phase (the batch before
    the first row with train/phase_rl > 0 ends), so phases that began at different env steps
    overlay; a run without a PPO phase is refused by name."""
    import plot_curves

    a = [{"step": s, "train/phase_rl": float(s > 20), "reward/total": 1.0} for s in (10, 20, 30, 40)]
    b = [{"step": s, "train/phase_rl": float(s > 50), "reward/total": 2.0} for s in (50, 60, 70)]
    assert [r["step"] for r in plot_curves.since_ppo(a, "a")] == [-10, 0, 10, 20]
    assert [r["step"] for r in plot_curves.since_ppo(b, "b")] == [0, 10, 20]
    with pytest.raises(ValueError, match="dagger_only: no row with train/phase_rl > 0"):
        plot_curves.since_ppo([{"step": 10, "train/phase_rl": 0.0}], "dagger_only")
    for name, rows in (("run_a", a), ("run_b", b), ("dagger_only", [{"step": 10, "train/phase_rl": 0.0}])):
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    figs = []
    monkeypatch.setattr(plot_curves.plt, "close", figs.append)
    monkeypatch.setattr(sys, "argv", ["plot_curves.py", str(tmp_path / "run_a"), str(tmp_path / "run_b"), "--compare",
                                      "--align", "ppo", "--panels", "phase", "-o", str(tmp_path / "p.png")])
    plot_curves.main()
    ax = figs[0].axes[0]
    assert [list(line.get_xdata()) for line in ax.lines] == [[-10, 0, 10, 20], [0, 10, 20]]
    assert ax.get_xlabel() == "environment steps since the PPO phase began"
    monkeypatch.setattr(sys, "argv", ["plot_curves.py", str(tmp_path / "run_a"), str(tmp_path / "dagger_only"),
                                      "--compare", "--align", "ppo"])
    with pytest.raises(SystemExit):
        plot_curves.main()
    assert "dagger_only: no row with train/phase_rl > 0" in capsys.readouterr().err
    monkeypatch.setattr(sys, "argv", ["plot_curves.py", str(tmp_path / "run_a"), "--align", "ppo"])
    with pytest.raises(SystemExit):
        plot_curves.main()
    assert "--align ppo needs --compare" in capsys.readouterr().err


def test_plot_curves_against_training_hours(tmp_path, monkeypatch):
    """--x hours: each row's x is the running sum of its iterations' collection and update
    seconds, in hours; a run that did not log them is refused by step."""
    import plot_curves

    rows = [{"step": 10, "reward/total": 1.0, "train/collect_s": 1800.0, "train/update_s": 0.0},
            {"step": 20, "reward/total": 2.0, "train/collect_s": 1800.0, "train/update_s": 1800.0}]
    assert plot_curves.training_hours(rows) == [0.5, 1.5]
    figs = []
    monkeypatch.setattr(plot_curves.plt, "close", figs.append)
    plot_curves.plot({"gpu": plot_curves.with_hours(rows)}, tmp_path / "h.png", "t", x="train/hours")
    ax = figs[0].axes[0]
    assert list(ax.lines[0].get_xdata()) == [0.5, 1.5] and ax.get_xlabel() == "training hours"
    with pytest.raises(ValueError, match="row at step 30 has no train/collect_s"):
        plot_curves.training_hours(rows + [{"step": 30, "reward/total": 3.0}])
    # rows from before collect_s was logged: the iteration's frames over the run's rate then
    older = [{"step": 3600, "train/fps_total": 1.0}, {"step": 7200, "train/fps_total": 2.0}]
    assert plot_curves.training_hours(older) == [1.0, 1.5]
    # an overlapped run (collector.overlap) collects during its update: its iteration seconds count, not the sum
    overlapped = [{"step": 10, "train/collect_s": 1800.0, "train/update_s": 1800.0, "train/iteration_s": 1800.0},
                  {"step": 20, "train/collect_s": 900.0, "train/update_s": 1800.0, "train/iteration_s": 3600.0}]
    assert plot_curves.training_hours(overlapped) == [0.5, 1.5]


def test_plot_curves_marks_a_panel_the_run_did_not_log(tmp_path, monkeypatch):
    """A panel none of whose keys the run logged (a student has no feedforward anneal) says so."""
    import plot_curves

    figs = []
    monkeypatch.setattr(plot_curves.plt, "close", figs.append)
    rows = [{"step": s, "reward/total": 0.1, "curriculum/gap": 1.0} for s in (10, 20)]
    plot_curves.plot(rows, tmp_path / "trails.png", "student", panels=plot_curves.TRAIL_PANELS)
    texts = {i: [t.get_text() for t in ax.texts] for i, ax in enumerate(figs[0].axes)}
    assert texts[4] == ["not logged by this run"]  # train/gait_feedforward
    assert texts[0] == [] and texts[5] == []  # curriculum and reward were drawn


def test_metrics_file_of_a_resumed_run_drops_the_rows_after_its_checkpoint(tmp_path):
    import json

    from legoh_rl.training.logging import MetricsFile

    path = tmp_path / "metrics.jsonl"
    first = MetricsFile(path)
    for step in (10, 20, 30, 40):  # killed after step 40; the last checkpoint was at step 20
        first.write(step, {"reward/total": step / 10})
    resumed = MetricsFile(path, resume_step=20)
    resumed.write(30, {"reward/total": 9.0})
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [(r["step"], r["reward/total"]) for r in rows] == [(10, 1.0), (20, 2.0), (30, 9.0)]
    MetricsFile(path, resume_step=100)  # nothing after the checkpoint: the file is left alone
    assert len(path.read_text().splitlines()) == 3


def test_gait_clock_policy_keeps_its_clock_through_export_and_evaluation(tmp_path):
    from legoh_rl.training.checkpoint import export_policy
    from legoh_rl.training.evaluation import EvalProtocol
    from legoh_rl.training.policies import load_policy

    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}",
                                                  "env.gait_period=0.6", "env.gait_stance=0.6",
                                                  "env.gait_amplitude=0.2", "env.gait_feedforward=0.5",
                                                  "+env.reward_overrides.gait_contact=1.0"]))
    slim = export_policy(ck / "last.pt", tmp_path / "oracle.pt")
    meta = load_checkpoint(slim)["meta"]
    assert meta["gait_period"] == 0.6 and meta["gait_stance"] == 0.6 and meta["obs_layout"]["proprio"] == (39,)
    assert meta["gait_amplitude"] == 0.2 and meta["gait_feedforward"] == 0.5  # the clock drives the targets
    env, policy, kind = load_policy(str(slim), EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=1),
                                    variants=1, num_threads=1)
    assert kind == "oracle" and env.cfg.gait_period == 0.6 and env.cfg.gait_stance == 0.6
    assert env.cfg.gait_amplitude == 0.2 and env.cfg.gait_feedforward == 0.5
    assert env.observation_spec["proprio"].shape[-1] == 39
    td = policy(env.reset())
    assert td["action"].shape == (1, env.A)


def test_gait_stats_read_feet_on_the_ground_for_a_standing_robot():
    import gait_stats

    s = gait_stats.gait_stats("zero", robots=4, seconds=1.5, settle_s=0.5)  # PD hold, before it tips over
    assert s["standing"] == 4 and s["airborne"] == 0.0
    assert 0.0 <= s["lift_mean"] <= s["lift_p95"] <= s["lift_max"] < 0.01
    with pytest.raises(ValueError, match="seconds > settle_s"):
        gait_stats.gait_stats("zero", seconds=0.5)


def test_action_noise_acts_with_the_std_it_sets_and_refuses_a_policy_without_one(tmp_path):
    """recipes/action_noise.py on a tiny oracle: std 0 is the mean action (no spread, the same
    outcome twice), a set std is the spread of action - loc it measures (past the run's max_std);
    the zero-action baseline has no std to set."""
    import action_noise

    from legoh_rl.training.checkpoint import export_policy

    ck = tmp_path / "ck"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={ck}", "model.max_std=0.5"]))
    slim = str(export_policy(ck / "last.pt", tmp_path / "oracle.pt"))
    rows = action_noise.noise_success(slim, "randommix", 0, robots=4, seconds=0.6, variants=1, stds=(0.0, 0.8, 0.0))
    assert [r["std"] for r in rows] == [0.0, 0.8, 0.0] and rows[0]["realised_std"] == 0.0
    assert rows[1]["realised_std"] == pytest.approx(0.8, rel=0.1)  # over 0.6 s x 4 robots x every action
    assert (rows[0]["ended"], rows[0]["success"]) == (rows[2]["ended"], rows[2]["success"])
    assert all(0 <= r["success"] <= r["ended"] <= r["robots"] == 4 for r in rows)
    with pytest.raises(ValueError, match="no Gaussian head"):
        action_noise.noise_success("zero", "randommix", 0, robots=1, seconds=0.1, variants=1, stds=(0.3,))
    with pytest.raises(ValueError, match=r"action stds must be >= 0, got \[-0.1\]"):
        action_noise.noise_success(slim, stds=(-0.1,))


def test_gait_figures_count_flights_tilt_and_detours_by_hand():
    """Two robots, four steps of 0.02 s: robot 0 leaps (both feet off at steps 1-2), robot 1 walks
    one foot at a time and falls after step 2 (its last step not counted)."""
    import gait_stats

    on, off = True, False
    contact = np.array([[[on, on], [on, off]], [[off, off], [off, on]], [[off, off], [on, off]],
                        [[on, on], [off, off]]])  # (T=4, N=2, 2)
    lift = np.where(contact, 0.0, 0.1)
    walking = np.array([[True, True], [True, True], [True, True], [True, False]])
    pos = np.zeros((4, 2, 2))
    pos[:, 1, 1] = [0.0, 0.1, -0.3, 5.0]  # robot 1 strays 0.3 m sideways (5 m after its fall: not counted)
    vel = np.zeros((4, 2, 2))
    vel[..., 0] = 0.5
    roll, pitch = np.zeros((4, 2)), np.zeros((4, 2))
    roll[:, 0], pitch[:, 0] = 0.3, 0.4  # robot 0 tilted 0.5 rad
    f = gait_stats.gait_figures(contact, lift, vel, pos, roll, pitch, walking, dt=0.02)
    # 7 walking steps: both feet off at robot 0's steps 1 and 2 only (robot 1's step 3 is after its fall)
    assert f["flight"] == pytest.approx(2 / 7) and f["flight_max_s"] == pytest.approx(0.04)
    assert f["airborne"] == pytest.approx(7 / 14)  # off feet among the 14 walking foot-steps (4 + 3)
    assert f["lift_max"] == 0.1 and f["lift_mean"] == pytest.approx(0.7 / 14) and f["speed"] == pytest.approx(0.5)
    assert f["lean_deg"] == pytest.approx(np.degrees(0.5) * 4 / 7)
    assert f["detour_m"] == pytest.approx((0.0 + 0.3) / 2)
    none = gait_stats.gait_figures(contact, lift, vel, pos, roll, pitch, np.zeros((4, 2), bool), dt=0.02)
    assert all(np.isnan(v) for v in none.values())
    assert f["landed"] == pytest.approx(2 / 7) and f["landed_max_s"] == pytest.approx(0.04)  # robot 0 lands at step 3


def test_gait_figures_tell_a_landed_leap_from_a_fall_into_a_pit():
    """Three robots, five steps of 0.1 s, both feet off in each: robot 0 leaps at steps 1-2 and lands
    on one foot at step 3; robot 1 drops at steps 2-3 and its episode ends at step 4 (a fall); robot 2
    leaves the ground at step 4, the window's last (not known to land)."""
    import gait_stats

    T, N = 5, 3
    contact = np.ones((T, N, 2), bool)
    contact[1:3, 0] = False
    contact[3, 0, 1] = False                       # robot 0 lands on its left foot
    contact[2:, 1] = False                         # robot 1 never lands
    contact[4, 2] = False
    walking = np.ones((T, N), bool)
    walking[4, 1] = False                          # robot 1's episode ends at step 4
    zeros2, zeros = np.zeros((T, N, 2)), np.zeros((T, N))
    f = gait_stats.gait_figures(contact, np.where(contact, 0.0, 0.2), zeros2, zeros2, zeros, zeros, walking, dt=0.1)
    walking_steps = 14                             # 5 + 4 + 5
    assert f["flight"] == pytest.approx((2 + 2 + 1) / walking_steps) and f["flight_max_s"] == pytest.approx(0.2)
    assert f["landed"] == pytest.approx(2 / walking_steps) and f["landed_max_s"] == pytest.approx(0.2)
    contact[3:, 0] = False                         # robot 0 is still up when the window ends: none landed
    g = gait_stats.gait_figures(contact, np.where(contact, 0.0, 0.2), zeros2, zeros2, zeros, zeros, walking, dt=0.1)
    assert g["landed"] == 0.0 and g["landed_max_s"] == 0.0 and g["flight_max_s"] == pytest.approx(0.4)


def test_the_committed_oracle_walks_lifting_its_feet():
    """checkpoints/oracle_h1_clocked.pt (gait feedforward) steps: feet well off the ground, forward speed."""
    import gait_stats

    s = gait_stats.gait_stats(str(RECIPES.parent / "checkpoints" / "oracle_h1_clocked.pt"), robots=4, seconds=4.0)
    assert s["standing"] == 4
    assert s["lift_p95"] > 0.10 and 0.2 < s["airborne"] < 0.6 and s["speed"] > 0.3, s


def test_the_foot_scan_oracle_walks_without_the_scripted_swing():
    """checkpoints/oracle_h1.pt (issue 52: the stage-9 oracle, near and far foot scan) acts with no gait
    feedforward: its meta records none, its env's PD targets get none, and it still steps (feet well
    off the ground, forward speed); the clock's phase stays in its observation."""
    import gait_stats

    from legoh_rl.training.policies import load_cell_policy

    path = str(RECIPES.parent / "checkpoints" / "oracle_h1.pt")
    meta = load_checkpoint(path)["meta"]
    assert "gait_feedforward" not in meta and meta["foot_scan"] and meta["foot_scan_far"] and meta["gait_period"] == 0.8
    env, _, _, base = load_cell_policy(path, "randommix", 0, 1, 0)
    assert base.cfg.gait_feedforward == 0.0 and env.observation_spec["scandots"].shape[-1] == 292
    s = gait_stats.gait_stats(path, robots=4, seconds=4.0)
    assert s["standing"] == 4
    # on flat RandomMix level 0 its swing rises 0.09 m (95th percentile; the stage-5 oracle's 0.15): a
    # shuffle would stay under 0.03 m and leave no foot in the air for a fifth of the steps
    assert s["lift_p95"] > 0.06 and 0.2 < s["airborne"] < 0.6 and s["speed"] > 0.3, s


def test_route_following_geometry_helpers_match_hand_computed_values():
    import route_following as rf

    assert rf.signed_yaw_deg(np.array([1.0, 1.0])) == pytest.approx(45.0)
    assert rf.signed_yaw_deg(np.array([0.0, -2.0])) == pytest.approx(-90.0)
    a170, am170 = np.radians(170.0), np.radians(-170.0)
    assert rf.angle_between_deg(np.array([math.cos(a170), math.sin(a170)]),
                                np.array([math.cos(am170), math.sin(am170)])) == pytest.approx(20.0)
    # heading 90 deg (facing +y), goal straight ahead in the yaw frame, moving along world -x + y:
    # 45 deg to the left of the goal; too slow: undefined; wraps across +-180
    course = rf.course_error_deg(np.array([[1.0, 0.0], [1.0, 0.0], [-1.0, 0.01]]),
                                 np.array([[-1.0, 1.0], [0.01, 0.0], [-1.0, -0.01]]), np.array([math.pi / 2, 0.0, 0.0]))
    assert course[0] == pytest.approx(45.0) and np.isnan(course[1]) and abs(course[2]) < 2.0
    # polyline (0,0) -> (2,0) -> (2,2); a second row with 2 vertices (its third is junk); a single point
    points = np.array([[[0, 0], [2, 0], [2, 2]], [[0, 0], [0, 4], [50, 50]], [[1, 1], [9, 9], [9, 9]]], float)
    count = np.array([3, 2, 1])
    xy = np.array([[1.0, 0.5], [3.0, 1.0], [1.0, 1.0]])
    assert rf.distance_to_polyline(xy, points, count) == pytest.approx([0.5, 3.0, 0.0])
    xy = np.array([[-1.0, 0.0], [-3.0, 5.0], [4.0, 5.0]])
    assert rf.distance_to_polyline(xy, points, count) == pytest.approx([1.0, math.hypot(3, 1), 5.0])


def test_route_following_of_a_standing_robot_and_of_the_committed_oracle():
    """A robot holding its pose at P_A faces its first expert goal and stands on the route; the
    committed oracle keeps within 0.5 m of the route, heading to its goals, for 6 s (the gait test
    checks that it walks)."""
    import route_following as rf

    zero = rf.route_following("zero", robots=2, seconds=0.4)
    assert zero["expert_yaw"].shape == (20, 2) and zero["time"][1] == pytest.approx(0.02)
    assert np.abs(zero["expert_yaw"][0]).max() < 1.0 and np.abs(zero["end_yaw"][0]).max() < 45.0
    assert zero["route_offset"].max() < 0.1
    assert np.isnan(zero["pred_yaw"]).all() and np.isnan(zero["pred_error"]).all()
    table = rf.summary_table(zero, bin_s=0.2)
    assert table.count("\n") == 3 and "| - | - |" in table and "course error" in table
    with pytest.raises(ValueError, match="robots >= 1"):
        rf.route_following("zero", robots=0)

    # the RandomMix oracle heads within ~10 deg of its goals; the whole-benchmark oracle, which also
    # learned to weave through forests, within ~18 deg (measured 17.7 on these trails)
    for name, yaw in (("oracle_h1_randommix.pt", 15.0), ("oracle_h1.pt", 20.0)):
        oracle = rf.route_following(str(RECIPES.parent / "checkpoints" / name), robots=4, seconds=6.0)
        assert np.isfinite(oracle["route_offset"]).all() and oracle["route_offset"].max() < 0.5, name
        assert np.nanmedian(np.abs(oracle["expert_yaw"])) < yaw, name


def test_route_following_can_give_the_student_the_expert_goal():
    """--goal-source expert replaces the RandomMix student's predicted goal by the expert one: it
    then keeps closer to the route by its sixth second (its own prediction, which follows P_B,
    leads it off; docs/history/results-sessions-1-12.md); the oracle has no goal to replace."""
    import route_following as rf

    student = str(RECIPES.parent / "checkpoints" / "student_h1_randommix.pt")
    own = rf.route_following(student, robots=2, seconds=6.0, variants=2)
    given = rf.route_following(student, robots=2, seconds=6.0, variants=2, goal_source="expert")
    assert np.isfinite(own["pred_yaw"]).all() and np.isfinite(given["pred_yaw"]).all()
    late = slice(250, 300)  # the last second
    assert np.nanmean(given["route_offset"][late]) < np.nanmean(own["route_offset"][late]), (
        np.nanmean(given["route_offset"][late]), np.nanmean(own["route_offset"][late]))
    with pytest.raises(ValueError, match="needs a student"):
        rf.route_following("zero", robots=1, seconds=0.1, goal_source="expert")
    with pytest.raises(ValueError, match="goal_source"):
        rf.route_following("zero", robots=1, seconds=0.1, goal_source="map")


def test_the_committed_g1_oracle_rebuilds_its_gait_clock():
    """checkpoints/oracle_g1.pt carries its gait clock in the meta block: the eval env
    it gets is G1's with the clock's feedforward at its wider swing, and the policy acts on it."""
    from legoh_rl.training.evaluation import EvalProtocol
    from legoh_rl.training.policies import load_policy

    protocol = EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=2)
    env, policy, kind = load_policy(str(RECIPES.parent / "checkpoints" / "oracle_g1.pt"), protocol, num_threads=1)
    assert kind == "oracle" and env.cfg.robot == "g1"
    assert env.cfg.gait_period == pytest.approx(0.8) and env.cfg.gait_feedforward == pytest.approx(1.0)
    assert env.cfg.gait_amplitude == pytest.approx(0.45)
    assert env.observation_spec["proprio"].shape[-1] == 45  # 43 + the clock's sin, cos
    td = policy(env.reset())
    assert td["action"].shape == (2, 12) and torch.isfinite(td["action"]).all()


def test_imitation_gap_table_of_a_hand_made_result():
    import imitation_gap as ig

    diff = np.zeros((50, 2, 3))
    diff[..., 0], diff[..., 1] = 0.1, -0.2
    diff[30:, 1] = np.nan  # robot 1's episode ended
    table = ig.gap_table({"time": np.arange(50) * 0.02, "diff": diff, "joints": ("a_joint", "b", "c")},
                         edges_s=(0.0, 0.5, 1.0))
    rows = table.splitlines()
    assert rows[0] == "| time (s) | mean abs | a | b | c |"
    assert rows[2] == "| 0-0.5 | 0.100 | +0.10 | -0.20 | +0.00 |" and rows[3].startswith("| 0.5-1 | 0.100 |")


def test_imitation_gap_labels_the_students_own_states_with_the_teacher():
    """The first row is the student's action minus the teacher's label on the reset state, computed
    here by hand from the same checkpoints; the options feed the locomotion module the expert goal
    and the teacher's latent."""
    import imitation_gap as ig
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from legoh_rl.training.distill import Teacher
    from legoh_rl.training.policies import load_cell_policy

    ck = RECIPES.parent / "checkpoints"
    student, teacher = str(ck / "student_h1_real_pits.pt"), str(ck / "oracle_h1_real_pits.pt")  # its teacher
    out = ig.imitation_gap(student, teacher, robots=2, seconds=0.3, variants=2)
    assert out["diff"].shape == (15, 2, 10) and np.isfinite(out["diff"]).all()
    env, policy, _, base = load_cell_policy(student, "randommix", 0, 2, 0, 2)
    env.set_seed(0)
    base.assign_tiles(np.zeros(2, int), np.full(2, base.trails.categories.index("randommix")))
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = policy(env.reset())
        tea = Teacher(teacher, "h1")
        by_hand = (td["action"] - tea.label(td.select(*tea.in_keys).copy())["action_tea"]).numpy()
    np.testing.assert_allclose(out["diff"][0], by_hand, atol=1e-5)
    both = ig.imitation_gap(student, teacher, robots=2, seconds=0.3, variants=2, goal_source="expert", latent="teacher")
    assert np.isfinite(both["diff"]).all() and not np.allclose(both["diff"], out["diff"])
    with pytest.raises(ValueError, match="latent must be 'student' or 'teacher', got 'z'"):
        ig.imitation_gap(student, teacher, latent="z")
    with pytest.raises(ValueError, match="needs a student checkpoint, got a oracle policy"):
        ig.imitation_gap(teacher, teacher, robots=1, seconds=0.1)


GAIT = ["env.gait_period=0.8", "env.gait_feedforward=1.0"]


def test_init_starts_a_fresh_run_from_a_policy_file(tmp_path):
    from legoh_rl.training.checkpoint import export_policy

    src = tmp_path / "src"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + GAIT + ["collector.total_frames=64", f"checkpoint.dir={src}"]))
    slim = export_policy(src / "last.pt", tmp_path / "policy.pt")
    parts = oracle_ppo.build(cfg_of("oracle_ppo", TINY + GAIT + [f"checkpoint.init={slim}",
                                                                 f"checkpoint.dir={tmp_path / 'new'}"]))
    saved = load_checkpoint(slim)["networks"]
    for k, v in parts.networks.state_dict().items():
        assert torch.equal(v, saved[k]), k
    assert parts.iteration == 0 and parts.frames == 0  # a new run: counters and optimiser fresh
    assert not parts.optim.state_dict()["state"]
    # a later stage of a feedforward anneal starts from the gain where the last one stopped
    later = oracle_ppo.build(cfg_of("oracle_ppo", TINY + GAIT + [f"checkpoint.init={slim}", "env.gait_feedforward=0.9",
                                                                 f"checkpoint.dir={tmp_path / 'later'}"]))
    assert later.env.cfg.gait_feedforward == 0.9


@pytest.mark.parametrize("extra,message", [
    (["model.layers=[32,32]"], r"other network sizes than model.layers"),
    (["env.gait_period=0.6"], r"gait_period: checkpoint has 0.8, this run needs 0.6"),
])
def test_init_from_a_policy_that_does_not_fit_is_refused(tmp_path, extra, message):
    src = tmp_path / "src"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + GAIT + ["collector.total_frames=32", f"checkpoint.dir={src}"]))
    cfg = cfg_of("oracle_ppo", TINY + GAIT + [f"checkpoint.init={src / 'last.pt'}", f"checkpoint.dir={tmp_path}/n"]
                 + extra)
    with pytest.raises(ValueError, match=message):
        oracle_ppo.build(cfg)


def test_init_widen_starts_a_foot_scan_run_acting_as_the_narrower_policy(tmp_path):
    """A policy trained on the 132 scandots starts a foot_scan run (222 columns) only with
    checkpoint.init_widen: the first scandot layers of actor and critic get zero weights on the 90
    new columns, everything else is copied, so the run's actions and values equal the old
    policy's on the same observation whatever the new columns hold. The widening is recorded in
    the meta block (kept on resume) and the config; evaluation rebuilds the foot scan."""
    from tensordict import TensorDict

    from legoh_rl.modules.oracle import make_oracle_actor, make_oracle_critic
    from legoh_rl.training.builders import oracle_networks
    from legoh_rl.training.evaluation import EvalProtocol
    from legoh_rl.training.policies import load_policy

    src = tmp_path / "src"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["collector.total_frames=32", f"checkpoint.dir={src}"]))
    scan = TINY + ["env.foot_scan=true", f"checkpoint.init={src / 'last.pt'}"]
    with pytest.raises(ValueError, match=r"last.pt's scandot_encoder.0.weight is \(128, 132\), this run's \(128, 222\)"
                                         r".*checkpoint.init_widen=true"):
        oracle_ppo.build(cfg_of("oracle_ppo", scan + [f"checkpoint.dir={tmp_path / 'refused'}"]))
    with pytest.raises(ValueError, match=r"init_widen=true: .* read this run's 132 scandot columns already"):
        oracle_ppo.build(cfg_of("oracle_ppo", TINY + [f"checkpoint.init={src / 'last.pt'}", "checkpoint.init_widen=true",
                                                      f"checkpoint.dir={tmp_path / 'same'}"]))
    cfg = cfg_of("oracle_ppo", scan + ["checkpoint.init_widen=true", f"checkpoint.dir={tmp_path / 'wide'}",
                                       "collector.total_frames=32"])
    parts = oracle_ppo.build(cfg)
    old_state = load_checkpoint(src / "last.pt")
    old = oracle_networks(old_state)
    layers = {"scandot_encoder.0.weight": [[128, 132], [128, 222]],
              "critic.scandot_encoder.0.weight": [[128, 132], [128, 222]]}
    record = {"checkpoint": str(src / "last.pt"), "scandots": [132, 222], "layers": layers}
    assert parts.meta["init_widened"] == record and parts.meta["foot_scan"] is True
    for key, value in parts.networks.state_dict().items():
        if key in layers:
            assert torch.equal(value[:, :132], old_state["networks"][key]) and not value[:, 132:].any(), key
        else:
            assert torch.equal(value, old_state["networks"][key]), key
    obs = parts.env.observation_spec.rand()
    obs["scandots"] = torch.rand(4, 222) * 2 - 1  # arbitrary values in the 90 new columns too
    narrow = TensorDict({k: obs[k] for k in ("proprio", "privileged", "expert_goals")}, batch_size=[4])
    narrow["scandots"] = obs["scandots"][:, :132]
    with torch.no_grad():
        new_loc = make_oracle_actor(parts.networks)(obs.clone())["loc"]
        old_loc = make_oracle_actor(old)(narrow.clone())["loc"]
        torch.testing.assert_close(new_loc, old_loc, atol=1e-6, rtol=1e-6)
        torch.testing.assert_close(make_oracle_critic(parts.networks)(obs.clone())["state_value"],
                                   make_oracle_critic(old)(narrow.clone())["state_value"], atol=1e-6, rtol=1e-6)
    oracle_ppo.train(cfg, env=parts.env)
    saved = load_checkpoint(tmp_path / "wide" / "last.pt")
    assert saved["meta"]["init_widened"] == record and saved["config"]["checkpoint"]["init_widen"] is True
    resumed = oracle_ppo.build(cfg_of("oracle_ppo", scan + ["checkpoint.init_widen=true", "checkpoint.resume=auto",
                                                            f"checkpoint.dir={tmp_path / 'wide'}"]))
    assert resumed.meta["init_widened"] == record
    env, policy, kind = load_policy(str(tmp_path / "wide" / "last.pt"),
                                    EvalProtocol(categories=("randommix",), levels=(0,), robots_per_cell=1))
    assert kind == "oracle" and env.cfg.foot_scan and env.observation_spec["scandots"].shape == (1, 222)
    assert policy(env.reset())["action"].shape == (1, env.A)


def test_init_widen_starts_a_far_scan_run_from_a_foot_scan_policy(tmp_path):
    """A foot-scan policy (222 scandot columns) starts a ``foot_scan_far`` run (292) with
    checkpoint.init_widen: the far scan's 70 columns come after the near scan's, so the widened
    first layers keep the policy's 222 columns and act as it did; the meta block records the far
    scan and the widening, and evaluation rebuilds both scans from it."""
    from legoh_rl.training.builders import policy_env_kwargs
    from legoh_rl.training.evaluation import EvalProtocol
    from legoh_rl.training.policies import load_policy

    src = tmp_path / "src"
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + ["env.foot_scan=true", "collector.total_frames=32",
                                                  f"checkpoint.dir={src}"]))
    far = TINY + ["env.foot_scan=true", "env.foot_scan_far=true", f"checkpoint.init={src / 'last.pt'}",
                  "collector.total_frames=32"]
    with pytest.raises(ValueError, match=r"\(128, 222\), this run's \(128, 292\).*env.foot_scan_far=True"):
        oracle_ppo.build(cfg_of("oracle_ppo", far + [f"checkpoint.dir={tmp_path / 'refused'}"]))
    cfg = cfg_of("oracle_ppo", far + ["checkpoint.init_widen=true", f"checkpoint.dir={tmp_path / 'far'}"])
    parts = oracle_ppo.build(cfg)
    assert parts.meta["init_widened"]["scandots"] == [222, 292]
    assert parts.meta["foot_scan"] is True and parts.meta["foot_scan_far"] is True
    old = load_checkpoint(src / "last.pt")["networks"]["scandot_encoder.0.weight"]
    new = parts.networks.state_dict()["scandot_encoder.0.weight"]
    assert torch.equal(new[:, :222], old) and not new[:, 222:].any()
    oracle_ppo.train(cfg, env=parts.env)
    saved = load_checkpoint(tmp_path / "far" / "last.pt")
    assert policy_env_kwargs(saved["meta"])["foot_scan_far"] is True
    assert policy_env_kwargs(load_checkpoint(src / "last.pt")["meta"])["foot_scan_far"] is False
    env, policy, kind = load_policy(str(tmp_path / "far" / "last.pt"),
                                    EvalProtocol(categories=("gap",), levels=(1,), robots_per_cell=1))
    assert env.cfg.foot_scan_far and env.observation_spec["scandots"].shape == (1, 292)
    assert policy(env.reset())["action"].shape == (1, env.A)


def test_init_curriculum_starts_the_worlds_on_the_levels_inits_run_left(tmp_path):
    """checkpoint.init_curriculum: a fresh run from another run's last.pt starts its worlds on the
    levels that run's curriculum left (set here by hand, as a curriculum would), not on env.levels;
    without the switch they start on env.levels. A slim export (no env state) and a run with other
    worlds (env.num_envs) are refused, naming the file and the field."""
    from legoh_rl.training.checkpoint import export_policy

    src = tmp_path / "src"
    levels = ["env.levels=[0,1,2,3,4]", "env.curriculum.enabled=true"]
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + levels + ["collector.total_frames=32", f"checkpoint.dir={src}"]))
    state = load_checkpoint(src / "last.pt")
    state["env"]["curriculum"]["levels"] = np.array([4, 3, 3, 1])
    save_checkpoint(src / "last.pt", state)
    init = TINY + levels + [f"checkpoint.init={src / 'last.pt'}"]
    parts = oracle_ppo.build(cfg_of("oracle_ppo", init + ["checkpoint.init_curriculum=true", f"checkpoint.dir={tmp_path / 'a'}"]))
    assert parts.env.curriculum.levels.tolist() == [4, 3, 3, 1]
    fresh = oracle_ppo.build(cfg_of("oracle_ppo", init + [f"checkpoint.dir={tmp_path / 'b'}"]))
    assert fresh.env.curriculum.levels.tolist() != [4, 3, 3, 1]
    with pytest.raises(ValueError, match=r"src/last.pt was trained with env.num_envs=4, this run has 8"):
        oracle_ppo.build(cfg_of("oracle_ppo", init + ["env.num_envs=8", "checkpoint.init_curriculum=true",
                                                      f"checkpoint.dir={tmp_path / 'c'}"]))
    slim = export_policy(src / "last.pt", tmp_path / "slim.pt")
    with pytest.raises(ValueError, match=r"slim.pt holds no curriculum state"):
        oracle_ppo.build(cfg_of("oracle_ppo", TINY + levels + [f"checkpoint.init={slim}", "checkpoint.init_curriculum=true",
                                                               f"checkpoint.dir={tmp_path / 'd'}"]))


def test_init_path_missing_is_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"checkpoint.init: no policy at /nope/policy.pt"):
        oracle_ppo.build(cfg_of("oracle_ppo", TINY + ["checkpoint.init=/nope/policy.pt", f"checkpoint.dir={tmp_path}"]))


def test_feedforward_anneal_reaches_zero_and_resumes_on_its_gain(tmp_path):
    """Gain 1 until 32 frames, 0 from 96: each batch is collected with the gain of the frames done
    before it, checkpoints record the annealed gain in their meta, and a resume mid-anneal continues."""
    ck = tmp_path / "ck"
    anneal = ["feedforward_anneal=[32,96]", f"checkpoint.dir={ck}", "checkpoint.every=1", "checkpoint.resume=auto"]
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + GAIT + anneal + ["collector.total_frames=64"]))
    saved = load_checkpoint(ck / "last.pt")
    assert saved["meta"]["gait_feedforward"] == pytest.approx(0.5)  # gain at 64 frames
    cfg = cfg_of("oracle_ppo", TINY + GAIT + anneal + ["collector.total_frames=128"])
    # a periodic checkpoint of an older version recorded the gain one batch behind: the schedule,
    # not the meta, sets the gain a resume collects with
    saved["meta"]["gait_feedforward"] = 0.75
    save_checkpoint(ck / "last.pt", saved)
    parts = oracle_ppo.build(cfg)
    assert parts.env.cfg.gait_feedforward == pytest.approx(0.5)
    oracle_ppo.train(cfg, env=parts.env)
    import plot_curves

    gains = [r["train/gait_feedforward"] for r in plot_curves.load(ck / "metrics.jsonl")]
    assert gains == pytest.approx([1.0, 1.0, 0.5, 0.0])
    final = load_checkpoint(ck / "last.pt")["meta"]
    assert "gait_feedforward" not in final and final["gait_period"] == 0.8  # a clock, no feedforward


def test_feedforward_anneal_needs_a_gain(tmp_path):
    with pytest.raises(ValueError, match=r"feedforward_anneal needs env.gait_feedforward > 0"):
        oracle_ppo.build(cfg_of("oracle_ppo", TINY + ["feedforward_anneal=[0,10]", f"checkpoint.dir={tmp_path}"]))


def test_trail_panels_weight_grouped_success_by_episodes(tmp_path):
    import plot_curves

    # two iterations: gap 100% of 1 episode, then 0% of 3 -> 25% over both, not the plain mean 50%
    assert plot_curves.weighted_running_mean([100.0, 0.0], [1.0, 3.0], 2) == [100.0, 25.0]
    assert math.isnan(plot_curves.weighted_running_mean([50.0, 10.0], [0.0, 0.0], 2)[1])  # no episodes: undefined
    rows = [{"step": 32 * (i + 1), "episode/gap/success": float(100 * (i % 2)), "episode/gap/episodes": 1.0 + i,
             "curriculum/gap": 0.1 * i, "train/gait_feedforward": 1.0, "reward/total": 0.1} for i in range(6)]
    _, _, mean = plot_curves._series(rows, "episode/gap/success", 2)
    assert mean[1] == pytest.approx(100 * 2 / 3)  # (0 x 1 + 100 x 2) / 3
    out = plot_curves.plot(rows, tmp_path / "trails.png", "t", smooth=2, panels=plot_curves.PANEL_SETS["trails"])
    assert out.stat().st_size > 1000


def test_cell_table_and_episode_csv_hand_values(tmp_path):
    from legoh_rl.training.evaluation import cell_table, write_episodes

    base = {"trail_completion": 0.0, "traverse_rate": 0.0, "mev": 0.0, "ttf": 1.0, "time_to_reach": math.nan}
    eps = [{**base, "run": r, "category": c, "level": lv, "success": s} for r, c, lv, s in (
        (0, "gap", 0, 100.0), (0, "gap", 0, 0.0), (1, "gap", 0, 100.0), (0, "gap", 2, 0.0), (1, "gap", 2, 0.0),
        (0, "ditch", 0, 100.0), (1, "ditch", 0, 100.0))]
    table = cell_table(eps).splitlines()
    assert table[0] == "| success | level 0 | level 2 | all |"
    # gap level 0: run 0 50, run 1 100 -> 75 +- 25; all of gap: run 0 33.3, run 1 50 -> 41.7 +- 8.3
    assert table[2] == "| gap | 75.0 ± 25.0 | 0.0 ± 0.0 | 41.7 ± 8.3 |"
    assert table[3] == "| ditch | 100.0 ± 0.0 | - | 100.0 ± 0.0 |"
    rows = write_episodes(eps, tmp_path / "e.csv").read_text().splitlines()
    assert len(rows) == 8 and rows[0].startswith("trail_completion,")


def test_experiment_oracle_h1_trails_composes_and_validates(tmp_path):
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_trails", f"checkpoint.dir={tmp_path}"])
    assert list(cfg.env.categories) == ["randommix", "ditch", "hurdle", "gap", "forest"] and cfg.env.curriculum
    assert list(cfg.feedforward_anneal) == [10_000_000, 50_000_000] and cfg.env.gait_feedforward == 1.0
    assert Path(cfg.checkpoint.init).is_file()  # the RandomMix oracle it starts from is committed
    oracle_ppo.validate(cfg)
    plain = cfg_of("oracle_ppo", [])
    assert plain.checkpoint.init is None and plain.get("feedforward_anneal") is None  # defaults untouched


def test_a_misspelt_experiment_is_an_error_not_the_defaults():
    from hydra.errors import MissingConfigException

    with pytest.raises(MissingConfigException, match="experiment/oracle_h1_trial"):
        cfg_of("oracle_ppo", ["experiment=oracle_h1_trial"])


def test_experiment_oracle_h1_footholds_is_stage_2_of_trails(tmp_path):
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_footholds", f"checkpoint.dir={tmp_path}"])
    trails = cfg_of("oracle_ppo", ["experiment=oracle_h1_trails", f"checkpoint.dir={tmp_path}"])
    assert cfg.checkpoint.init == "runs/oracle_h1_trails/last.pt" and Path(cfg.checkpoint.init).is_file()
    assert dict(cfg.env.reward_overrides) == {**trails.env.reward_overrides, "feet_in_pit": -5.0}
    assert cfg.ppo == trails.ppo and cfg.model == trails.model and cfg.env.num_envs == trails.env.num_envs
    oracle_ppo.validate(cfg)
    env = env_config(cfg.env, mode="oracle")
    assert env.category_weights == (1.0, 1.5, 1.0, 1.5, 0.6) and env.feet_edge_from_level == 1
    # the feedforward gain goes on along stage 1's line (1 -> 0 over its frames 10M-50M) from where it ended
    assert cfg.feedforward_anneal == "inherit"
    schedule, source = oracle_ppo.feedforward_schedule(cfg)
    assert schedule == FeedforwardSchedule(0.9222176, (0, 36_888_704)), schedule
    assert source == "checkpoint.init runs/oracle_h1_trails/last.pt at its 13111296 frames"
    assert schedule.gain == load_checkpoint(cfg.checkpoint.init)["meta"]["gait_feedforward"]


def test_experiment_oracle_h1_pit_rungs_is_stage_3_with_shallower_training_pits(tmp_path):
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_pit_rungs", f"checkpoint.dir={tmp_path}"])
    footholds = cfg_of("oracle_ppo", ["experiment=oracle_h1_footholds", f"checkpoint.dir={tmp_path}"])
    assert cfg.checkpoint.init == "runs/oracle_h1_footholds/last.pt" and Path(cfg.checkpoint.init).is_file()
    assert cfg.env.reward_overrides == footholds.env.reward_overrides and cfg.ppo == footholds.ppo
    oracle_ppo.validate(cfg)
    env = env_config(cfg.env, mode="oracle")
    assert env.pit_depths == (0.1, 0.3, 0.6, 1.0, 1.0) and env.category_weights == (1.0, 1.5, 1.0, 1.5, 0.6)
    # the init checkpoint's gain, annealed on stage 2's slope (0.922 over 36.9M frames, as its run recorded)
    start = load_checkpoint(cfg.checkpoint.init)
    assert cfg.feedforward_anneal == "inherit"
    schedule, _ = oracle_ppo.feedforward_schedule(cfg)
    assert schedule.gain == start["meta"]["gait_feedforward"] == 0.5082723642276423
    assert schedule.anneal == (0, 36_900_000 - start["frames"]) == (0, 20_341_920)
    assert math.isclose(schedule.gain / schedule.anneal[1], 0.922 / 36_900_000)


def test_experiment_oracle_h1_foot_scan_is_stage_4_widening_stage_3(tmp_path):
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_h1_foot_scan", f"checkpoint.dir={tmp_path}"])
    rungs = cfg_of("oracle_ppo", ["experiment=oracle_h1_pit_rungs", f"checkpoint.dir={tmp_path}"])
    assert cfg.checkpoint.init == "runs/oracle_h1_pit_rungs/last.pt" and Path(cfg.checkpoint.init).is_file()
    assert cfg.checkpoint.init_widen is True and cfg.collector.total_frames == 20_000_000
    assert {**cfg.env, "foot_scan": False} == dict(rungs.env) and cfg.env.foot_scan is True
    assert cfg.ppo == rungs.ppo and cfg.model == rungs.model
    oracle_ppo.validate(cfg)
    schedule, _ = oracle_ppo.feedforward_schedule(cfg)  # stage 3's gain at its end, on its slope
    assert schedule.gain == load_checkpoint(cfg.checkpoint.init)["meta"]["gait_feedforward"]
    # stage 3's networks widen onto the foot scan's 222 columns (a small env of the same settings)
    small = cfg_of("oracle_ppo", ["experiment=oracle_h1_foot_scan", f"checkpoint.dir={tmp_path}", "env.num_envs=2",
                                  "env.categories=[randommix]", "env.category_weights=null", "env.variants=1",
                                  "env.num_threads=1", "logger.backend=csv"])
    parts = oracle_ppo.build(small)
    assert parts.meta["init_widened"]["scandots"] == [132, 222] and parts.env.cfg.gait_feedforward == schedule.gain


def test_experiment_oracle_g1_foot_scan_is_h1s_stage_4_on_g1s_networks(tmp_path):
    """G1 without the feedforward: H1's stage-4 settings but the robot and its swing, started from
    oracle_g1_trails' final state (widened), on that run's anneal (0.58 at its end, 0 ~23M frames on)."""
    cfg = cfg_of("oracle_ppo", ["experiment=oracle_g1_foot_scan", f"checkpoint.dir={tmp_path}"])
    h1 = cfg_of("oracle_ppo", ["experiment=oracle_h1_foot_scan", f"checkpoint.dir={tmp_path}"])
    g1 = cfg_of("oracle_ppo", ["experiment=oracle_g1_trails", f"checkpoint.dir={tmp_path}"])
    assert {**cfg.env, "robot": "h1", "gait_amplitude": h1.env.gait_amplitude} == dict(h1.env)
    assert cfg.env.robot == "g1" and cfg.env.gait_amplitude == g1.env.gait_amplitude
    assert cfg.ppo == h1.ppo and cfg.model == h1.model and cfg.collector.overlap is True and cfg.stages is None
    assert Path(cfg.checkpoint.init).is_file() and cfg.checkpoint.init_widen is True
    oracle_ppo.validate(cfg)
    schedule, _ = oracle_ppo.feedforward_schedule(cfg)
    init = load_checkpoint(cfg.checkpoint.init)
    assert init["meta"]["robot"] == "g1" and schedule.gain == init["meta"]["gait_feedforward"]
    assert math.isclose(schedule.gain / schedule.anneal[1], 1.0 / 40_000_000)  # oracle_g1_trails' slope
    assert schedule.anneal[1] < cfg.collector.total_frames
    small = cfg_of("oracle_ppo", ["experiment=oracle_g1_foot_scan", f"checkpoint.dir={tmp_path}", "env.num_envs=2",
                                  "env.categories=[randommix]", "env.category_weights=null", "env.variants=1",
                                  "env.num_threads=1", "logger.backend=csv"])
    parts = oracle_ppo.build(small)
    assert parts.meta["init_widened"]["scandots"] == [132, 222] and parts.env.cfg.gait_feedforward == schedule.gain


@pytest.mark.parametrize("run", ["oracle_h1_footholds", "oracle_h1_pit_rungs"])
def test_a_resumed_inheriting_stage_keeps_the_schedule_its_own_state_recorded(tmp_path, run):
    """The committed run states were started with the gains copied by hand: resumed under
    ``feedforward_anneal: inherit`` they go on with the schedule their own config recorded, so the
    gain their resume collects with is the one their meta block holds."""
    shutil.copy(ROOT / "runs" / run / "last.pt", tmp_path / "last.pt")
    cfg = cfg_of("oracle_ppo", [f"experiment={run}", f"checkpoint.dir={tmp_path}", "checkpoint.resume=auto"])
    oracle_ppo.validate(cfg)
    schedule, source = oracle_ppo.feedforward_schedule(cfg)
    state = load_checkpoint(tmp_path / "last.pt")
    recorded = state["config"]
    assert schedule == FeedforwardSchedule(recorded["env"]["gait_feedforward"], tuple(recorded["feedforward_anneal"]))
    assert schedule.at(state["frames"]) == state["meta"]["gait_feedforward"]
    assert source == f"the run's own {tmp_path / 'last.pt'}"


def _with_state(path, **state):
    """A hand-made checkpoint at ``path`` (a meta block and what the schedule readers look at)."""
    save_checkpoint(path, {"meta": {"kind": "oracle"}, **state})
    return path


def test_inherit_reads_the_record_of_its_init_or_its_resume(tmp_path):
    init = _with_state(tmp_path / "init.pt", frames=600, feedforward_schedule={"gain": 0.8, "anneal": [200, 1000]})
    base = TINY + GAIT + ["feedforward_anneal=inherit", f"checkpoint.init={init}"]
    fresh = cfg_of("oracle_ppo", base + [f"checkpoint.dir={tmp_path / 'fresh'}"])
    oracle_ppo.validate(fresh)
    assert oracle_ppo.feedforward_schedule(fresh)[0] == FeedforwardSchedule(0.4, (0, 400))  # 0.8 x 400 / 800
    (tmp_path / "run").mkdir()
    _with_state(tmp_path / "run" / "last.pt", frames=100, feedforward_schedule={"gain": 0.3, "anneal": [0, 50_000]})
    resumed = cfg_of("oracle_ppo", base + [f"checkpoint.dir={tmp_path / 'run'}", "checkpoint.resume=auto"])
    assert oracle_ppo.feedforward_schedule(resumed)[0] == FeedforwardSchedule(0.3, (0, 50_000))  # its own


def test_inherit_without_an_init_or_a_recorded_schedule_is_refused_naming_the_file(tmp_path):
    base = TINY + GAIT + ["feedforward_anneal=inherit", f"checkpoint.dir={tmp_path / 'run'}"]
    with pytest.raises(ValueError, match=r"feedforward_anneal=inherit goes on with checkpoint.init's gait feedforward "
                                         r"schedule: set checkpoint.init \(got null\)"):
        oracle_ppo.validate(cfg_of("oracle_ppo", base))
    bare = _with_state(tmp_path / "bare.pt", frames=64)
    with pytest.raises(ValueError, match=rf"{bare} records no gait feedforward schedule"):
        oracle_ppo.validate(cfg_of("oracle_ppo", base + [f"checkpoint.init={bare}"]))
    no_frames = _with_state(tmp_path / "no_frames.pt", feedforward_schedule={"gain": 1.0, "anneal": None})
    with pytest.raises(ValueError, match=rf"{no_frames} records no frame count"):
        oracle_ppo.validate(cfg_of("oracle_ppo", base + [f"checkpoint.init={no_frames}"]))
    clockless = _with_state(tmp_path / "clock.pt", frames=0, feedforward_schedule={"gain": 1.0, "anneal": None})
    with pytest.raises(ValueError, match=r"the inherited gain 1.0 needs a gait clock, set env.gait_period > 0"):
        oracle_ppo.validate(cfg_of("oracle_ppo", TINY + ["feedforward_anneal=inherit", f"checkpoint.init={clockless}",
                                                         f"checkpoint.dir={tmp_path / 'run'}"]))
    with pytest.raises(ValueError, match=r"feedforward_anneal must be \[start_frames, end_frames\] or inherit, "
                                         r"got 'inherits'"):
        oracle_ppo.validate(cfg_of("oracle_ppo", base + ["feedforward_anneal=inherits"]))


def test_a_stage_inherits_its_inits_anneal_and_records_it(tmp_path):
    """Run A anneals 1 -> 0 over frames [32, 96] and stops at 64 (gain 0.5); run B, started from
    A's last.pt with inherit, collects from 0.5 on A's slope and records the schedule it followed."""
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + GAIT + ["feedforward_anneal=[32,96]", "collector.total_frames=64",
                                                         f"checkpoint.dir={tmp_path / 'a'}"]))
    a = load_checkpoint(tmp_path / "a" / "last.pt")
    assert a["feedforward_schedule"] == {"gain": 1.0, "anneal": [32, 96]} and a["meta"]["gait_feedforward"] == 0.5
    oracle_ppo.train(cfg_of("oracle_ppo", TINY + GAIT + ["feedforward_anneal=inherit", "collector.total_frames=32",
                                                         "env.gait_feedforward=0.1",  # not read under inherit
                                                         f"checkpoint.init={tmp_path / 'a' / 'last.pt'}",
                                                         f"checkpoint.dir={tmp_path / 'b'}"]))
    b = load_checkpoint(tmp_path / "b" / "last.pt")
    assert b["feedforward_schedule"] == {"gain": 0.5, "anneal": [0, 32]}
    assert b["config"]["feedforward_anneal"] == "inherit" and "gait_feedforward" not in b["meta"]  # 0 at 32
    import plot_curves

    assert [r["train/gait_feedforward"] for r in plot_curves.load(tmp_path / "b" / "metrics.jsonl")] == [0.5]


def test_demo_help_prints_usage_and_runs_nothing(capsys):
    from legoh_rl import demo

    with pytest.raises(SystemExit) as exit_info:
        demo.main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m legoh_rl.demo") and "short oracle PPO training" in out
    with pytest.raises(SystemExit):
        demo.main(["--bogus"])


@pytest.mark.parametrize("kwargs, message", [
    ({"categories": ("randommix", "swamp")}, "unknown categories ['swamp']; valid: ["),
    ({"levels": (0, 5)}, "levels [5] out of range; valid: 0..4"),
    ({"levels": (1, 1)}, "levels must be distinct, got [1, 1] (repeated: [1])"),
    ({"categories": ("gap", "gap")}, "categories must be distinct, got ['gap', 'gap']"),
    ({"robots_per_cell": 0}, "robots_per_cell and runs must be >= 1, got 0, 1"),
])
def test_eval_protocol_refuses_bad_cells_naming_them(kwargs, message):
    """evaluate.py, paper_tables.py and the probes share these checks, before any env is built."""
    from legoh_rl.training.evaluation import EvalProtocol

    cells = {"categories": ("randommix",), "levels": (0,), **kwargs}
    with pytest.raises(ValueError, match=re.escape(message)):
        EvalProtocol(**cells)
    assert EvalProtocol(categories=("hill", "gap"), levels=(0, 4)).num_worlds == 16  # hill: out of domain, valid


def test_provenance_prints_the_lineage_the_command_and_the_config(tmp_path, capsys):
    """recipes/provenance.py: a committed student's experiment, its command, its teacher's own
    lineage (a renamed teacher followed), and the resolved config it trained with."""
    import provenance

    assert provenance.main([str(ROOT / "checkpoints" / "student_h1_clocked.pt"), "--config"]) == 0
    out = capsys.readouterr().out
    assert "experiment student_h1: student_h1.yaml <- student_h1_trails.yaml" in out
    assert "trained by: python recipes/unified.py experiment=student_h1 checkpoint.resume=auto" in out
    assert "the experiment today gives the recorded settings" in out
    assert "teacher:" in out and "checkpoints/oracle_h1_clocked.pt" in out  # recorded as oracle_h1.pt, since renamed
    assert "experiment oracle_h1_footholds: oracle_h1_footholds.yaml <- oracle_h1_trails.yaml" in out
    assert "resolved config:" in out and "dagger_iters: 5000" in out
    # recorded in the old layout of the env section, printed in today's (upgrade_recorded_config)
    assert "  depth_camera:\n" in out and "  timestep: 0.005" in out and "depth_source" not in out
    # the foot-scan oracle's student, its teacher recorded by the name it has again
    assert provenance.main([str(ROOT / "checkpoints" / "student_h1_foot_scan.pt")]) == 0
    out = capsys.readouterr().out
    assert "experiment student_h1_foot_scan: student_h1_foot_scan.yaml <- student_h1.yaml" in out
    assert "teacher:\n    checkpoints/oracle_h1_foot_scan.pt\n" in out and "experiment oracle_h1_foot_scan:" in out
    # the stage-5 oracle's student (student_h1.pt until 2026-12-08), its teacher recorded as
    # checkpoints/oracle_h1.pt, the stage-5 oracle's name until 2026-12-07, found by its digest under
    # the name it has since
    assert provenance.main([str(ROOT / "checkpoints" / "student_h1_real_pits.pt")]) == 0
    out = capsys.readouterr().out
    assert "experiment student_h1_real_pits: student_h1_real_pits.yaml <- student_h1_foot_scan.yaml" in out
    assert "teacher:\n    checkpoints/oracle_h1_real_pits.pt\n" in out and "experiment oracle_h1_real_pits:" in out
    assert provenance.experiment_chain("student_g1") == ["student_g1", "student_h1", "student_h1_trails"]
    changed, added = provenance.differences({"a": 1, "b": {"c": 2}, "gone": 0}, {"a": 1, "b": {"c": 3, "d": 4}})
    assert changed == ["b.c: recorded 2, today 3", "gone: recorded 0, today '<no longer a setting>'"]
    assert added == ["b.d"]
    # a checkpoint of the plain recipe config says so
    state = load_checkpoint(ROOT / "checkpoints" / "oracle_h1.pt")
    state["meta"] = {k: v for k, v in state["meta"].items() if k != "experiment"}
    state["config"] = {}
    save_checkpoint(tmp_path / "plain.pt", state)
    provenance.main([str(tmp_path / "plain.pt")])
    assert "no named experiment in its meta block" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        provenance.main([str(tmp_path / "missing.pt")])
    assert "no checkpoint at" in capsys.readouterr().err


def test_plot_curves_hours_at_measured_rates(tmp_path, monkeypatch):
    """--x hours --rate: each run's x is its env steps over its own measured steps/s, in hours."""
    import plot_curves

    for name in ("fast", "slow"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.jsonl").write_text(
            "\n".join(json.dumps({"step": s, "episode/success": 1.0, "train/collect_s": 1.0, "train/update_s": 1.0})
                      for s in (7200, 14400)) + "\n")
    figs = []
    monkeypatch.setattr(plot_curves.plt, "close", figs.append)
    monkeypatch.setattr(sys, "argv", ["plot_curves.py", str(tmp_path / "fast"), str(tmp_path / "slow"), "--compare",
                                      "--x", "hours", "--rate", "2", "1", "-o", str(tmp_path / "c.png")])
    plot_curves.main()
    lines = {ln.get_label(): list(ln.get_xdata()) for ln in figs[0].axes[1].lines}  # the success panel
    assert lines["fast"] == [1.0, 2.0] and lines["slow"] == [2.0, 4.0]
    monkeypatch.setattr(sys, "argv", ["plot_curves.py", str(tmp_path / "fast"), "--rate", "2"])
    with pytest.raises(SystemExit):
        plot_curves.main()
