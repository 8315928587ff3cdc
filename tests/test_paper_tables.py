"""recipes/paper_tables.py and legoh_rl/paper_tables/: the transcribed paper numbers, the row ->
checkpoint mapping on hand-made meta blocks, the tables written from hand-made results, the
command line's errors, one tiny end-to-end run of the committed H1 oracle, and the committed
tables rendered again from the committed evaluation archive.

Why one file of ~550 lines: the tests share the hand-made checkpoints, meta blocks and aggregates
defined here, and the paper's numbers are checked against the tex one by one."""

import csv
import filecmp
import hashlib
import json
import math
import re
import shutil
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes"))

import paper_tables as recipe  # noqa: E402

import legoh_rl.paper_tables as pt  # noqa: E402
from legoh_rl.paper_tables import render  # noqa: E402
from legoh_rl.training import eval_run  # noqa: E402

TEX = ROOT.parent / "shared" / "reference" / "lego-h-paper.tex"
SIX = ("success", "trail_completion", "traverse_rate", "mev", "ttf", "time_to_reach")


def paper_row(table: str, method: str, group: str = "overall") -> pt.PaperRow:
    return next(r for r in pt.TABLES[table].rows if r.method == method and r.group == group)


# ---------------------------------------------------------------------------------------------
# the paper's numbers


def test_hand_picked_paper_numbers():
    assert paper_row("ablation", "LEGO-H").paper["success"] == (68.40, 1.34)  # RESULTS.md
    assert paper_row("ablation", "Oracle").paper["success"] == (71.20, 0.72)
    assert paper_row("ablation", "Oracle").paper["time_to_reach"] == (4.59, 0.08)
    assert paper_row("ablation", "w TC-ViT (no HLM)").paper["mev"] == (10.40, 1.50)
    assert paper_row("ablation", "Vanilla (ConvGRU)").paper["ttf"] == (5.36, 0.10)
    assert paper_row("g1", "G1 (LEGO-H)").paper["success"] == (63.96, 1.03)  # RESULTS.md
    assert paper_row("g1", "G1 (LEGO-H)").paper["trail_completion"] == (38.94, 0.63)
    assert paper_row("benchmark", "RMA-H").paper["traverse_rate"] == (74.61, 0.93)
    assert paper_row("benchmark", "RMA-B").paper["ttf"] == (5.22, 0.03)
    assert paper_row("gru_ct", "w CTs").paper == {"success": (27.85, 1.02), "trail_completion": None,
                                                  "traverse_rate": None, "mev": None, "ttf": (5.44, 0.34),
                                                  "time_to_reach": None}
    assert paper_row("hlm_vae", "Vanilla VAE").paper["mev"] == (9.26, 1.08)
    assert paper_row("hlm_plugin", "EP-H + HLM").paper["time_to_reach"] == (7.80, 0.37)
    assert paper_row("terrains", "RMA-B", "hurdle").paper["success"] == (83.04, 0.27)
    assert paper_row("terrains", "EP-H", "forest").paper["trail_completion"] == (1.04, 0.16)
    assert tuple(pt.METRICS) == SIX
    assert [higher for _, higher in pt.METRICS.values()] == [True, True, True, False, True, False]


def test_every_paper_row_has_the_six_metrics_and_a_checkpoint_row():
    labels = {t.name: t.label for t in pt.TABLES.values()}
    assert labels == {"ablation": "tab:ablation_h1", "ablation_converged": "tab:ablation_h1", "benchmark": "tab:hiking_benchmark", "gru_ct": "tab:ablation_gru",
                      "hlm_vae": "tab:vae", "hlm_plugin": "plug", "g1": "tab:g1",
                      "terrains": "tab:hiking_benchmark_terrains"}
    lego_h = paper_row("ablation", "LEGO-H").paper
    for table in pt.TABLES.values():
        assert table.rows
        for row in table.rows:
            assert row.key in pt.ROWS
            if row.paper is None:  # ours only (the G1 oracle)
                assert row.key == "g1_oracle"
                continue
            assert tuple(row.paper) == SIX
            given = [m for m in SIX if row.paper[m] is not None]
            assert given == (["success", "ttf"] if table.name == "gru_ct" else list(SIX)), (table.name, row.method)
            for m in given:
                mean, std = row.paper[m]
                assert mean >= 0 and 0 <= std < 5, (table.name, row.method, m)
            if row.key in ("h1_lego_h", "h1_lego_h_long", "h1_lego_h_converged"):  # LEGO-H on H1 is one set of figures in every table
                assert all(row.paper[m] == lego_h[m] for m in given), table.name
    assert {r.group for r in pt.TABLES["terrains"].rows} == {"randommix", "ditch", "hurdle", "gap", "forest"}


@pytest.mark.skipif(not TEX.is_file(), reason="the paper's tex is not beside the checkout")
def test_every_paper_number_matches_the_tex():
    tex = TEX.read_text()
    num = re.compile(r"\$(\d+\.\d+)\\pm(\d+\.\d+)\$")
    names = {"Success": "success", "Trail": "trail_completion", "Traverse": "traverse_rate", "MEV": "mev",
             "TTF": "ttf", "T2R": "time_to_reach", "Time-to-Reach": "time_to_reach"}
    for table in pt.TABLES.values():
        at = tex.index(f"\\label{{{table.label}}}")
        body = tex[tex.rfind("\\begin{table", 0, at):tex.index("\\end{table", at)]
        body = body[body.index("\\midrule"):]
        if table.name == "terrains":  # methods as rows, one block per category
            parts = re.split(r"\\textbf\{(RandomMix|Ditch|Hurdle|Gap|Forest)\}", body)
            for category, block in zip(parts[1::2], parts[2::2], strict=True):
                for line in block.splitlines():
                    m = re.match(r"\s*(EP-H|RMA-B)\s*&", line)
                    if m:
                        want = [(float(a), float(b)) for a, b in num.findall(line)]
                        got = paper_row("terrains", m.group(1), category.lower()).paper
                        assert [got[k] for k in SIX] == want, (category, m.group(1))
            continue
        # the longer-trained LEGO-H repeats the LEGO-H column under ours; the tex prints it once
        cols = [r for r in table.rows if r.paper is not None and r.key != "h1_lego_h_long"]
        seen = set()
        for line in body.splitlines():
            if "\\pm" not in line:
                continue
            metric = next(v for k, v in names.items() if line.strip().startswith(k))
            seen.add(metric)
            assert [r.paper[metric] for r in cols] == [(float(a), float(b)) for a, b in num.findall(line)], \
                (table.name, metric)
        assert all(r.paper[m] is None for r in cols for m in SIX if m not in seen)


# ---------------------------------------------------------------------------------------------
# row -> checkpoint


def student_meta(robot="h1", perception="tcvit", **extra):
    return {"robot": robot, "kind": "student", "perception": perception, "preset": "cpu", **extra}


def hlm_config(enabled, vanilla_vae=False):
    return {"hlm": {"enabled": enabled, "vanilla_vae": vanilla_vae}}


def test_checkpoint_info_reads_hlm_from_the_meta_or_else_the_training_config():
    info = pt.checkpoint_info(student_meta(), hlm_config(False))
    assert (info.robot, info.kind, info.perception, info.hlm, info.vanilla_vae) == ("h1", "student", "tcvit", False, False)
    assert pt.checkpoint_info(student_meta(), hlm_config(True)).hlm is True
    assert pt.checkpoint_info(student_meta(hlm=True), hlm_config(False)).hlm is True  # the meta wins
    vae = pt.checkpoint_info(student_meta(), hlm_config(True, vanilla_vae=True))
    assert vae.hlm and vae.vanilla_vae
    assert pt.checkpoint_info(student_meta(), hlm_config(False, vanilla_vae=True)).vanilla_vae is False  # no HLM: no prior
    warm = hlm_config(True)
    warm["hlm"]["warmup_iters"] = 100
    assert pt.checkpoint_info(student_meta(), warm, iteration=99).hlm is False  # L_hie not joined yet
    # iteration 100: updates 0-99 done, none with L_hie (it joins at update 100)
    assert pt.checkpoint_info(student_meta(), warm, iteration=100).hlm is False
    assert pt.checkpoint_info(student_meta(), warm, iteration=101).hlm is True
    unknown = pt.checkpoint_info(student_meta(), None)
    assert unknown.hlm is None and unknown.vanilla_vae is None
    oracle = pt.checkpoint_info({"robot": "h1", "kind": "oracle"}, hlm_config(True))
    assert oracle.kind == "oracle" and oracle.hlm is None and oracle.perception is None
    assert pt.describe(pt.checkpoint_info(student_meta(), hlm_config(False))) == "H1 student (tcvit, HLM off)"
    assert pt.describe(vae) == "H1 student (tcvit, HLM on, vanilla VAE)"


def test_rows_take_only_checkpoints_that_match_them():
    rows = pt.ROWS
    no_hlm = pt.checkpoint_info(student_meta(), hlm_config(False))
    with_hlm = pt.checkpoint_info(student_meta(), hlm_config(True))
    assert pt.mismatch(rows["h1_no_hlm"], no_hlm) is None
    assert pt.mismatch(rows["h1_lego_h"], no_hlm) == "HLM off, the row needs HLM on"
    assert pt.mismatch(rows["h1_lego_h"], with_hlm) is None
    assert pt.mismatch(rows["h1_no_hlm"], with_hlm) == "HLM on, the row needs HLM off"
    assert pt.mismatch(rows["g1_lego_h"], with_hlm) == "robot 'h1', the row needs 'g1'"
    assert "HLM on or off is not recorded" in pt.mismatch(rows["h1_lego_h"], pt.checkpoint_info(student_meta()))
    vae = pt.checkpoint_info(student_meta(), hlm_config(True, vanilla_vae=True))
    assert pt.mismatch(rows["h1_vanilla_vae"], vae) is None
    assert pt.mismatch(rows["h1_lego_h"], vae) == "a vanilla VAE, the row needs the masked VAE"
    eph = pt.checkpoint_info(student_meta(perception="eph"), hlm_config(True))
    assert pt.mismatch(rows["h1_eph_hlm"], eph) is None
    assert pt.mismatch(rows["h1_eph"], eph) == "HLM on, the row needs HLM off"
    assert pt.mismatch(rows["h1_lego_h"], eph) == "perception 'eph', the row needs 'tcvit'"
    for key, perception in [("h1_vanilla", "vanilla"), ("h1_ct", "tcvit_ct"), ("h1_rmah", "rmah"), ("h1_rmab", "rmab")]:
        locomotion = {"locomotion": "oracle"} if key.startswith("h1_rma") else {}
        for hlm in (True, False):  # the paper does not say: either
            info = pt.checkpoint_info(student_meta(perception=perception, **locomotion), hlm_config(hlm))
            assert pt.mismatch(rows[key], info) is None
    # RMA is "a frozen oracle policy with an adapter": an adapter with a learned locomotion is not the row
    learned = pt.checkpoint_info(student_meta(perception="rmah"), hlm_config(False))
    assert learned.locomotion == "learned"
    assert pt.mismatch(rows["h1_rmah"], learned) == "learned locomotion, the row needs oracle (student.locomotion=oracle)"
    assert pt.mismatch(rows["h1_vanilla"], pt.checkpoint_info(student_meta(perception="vanilla", locomotion="oracle"),
                                                              hlm_config(False))) is not None
    oracle = pt.checkpoint_info({"robot": "h1", "kind": "oracle"})
    assert pt.mismatch(rows["h1_oracle"], oracle) is None
    assert pt.mismatch(rows["h1_lego_h"], oracle) == "kind 'oracle', the row needs 'student'"
    assert rows["g1_lego_h"].paths == ("student_g1.pt",)
    assert rows["h1_lego_h_long"].paths == ("student_h1.pt",)
    assert pt.mismatch(rows["h1_lego_h_long"], no_hlm) == "HLM off, the row needs HLM on"
    # the ablation rows read only checkpoints/ablations/ (one training budget for Table 1)
    for key in ("h1_lego_h", "h1_no_hlm", "h1_vanilla", "h1_eph", "h1_rmah", "h1_rmab", "h1_ct", "h1_vanilla_vae",
                "h1_eph_hlm"):
        assert rows[key].paths == (f"ablations/{key}.pt", f"ablations/{key}_seed*.pt")


def fake_checkpoint(path: Path, meta: dict, config: dict | None = None, frames: int | None = None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"meta": meta, **({"config": config} if config else {}),
                **({"frames": frames} if frames is not None else {})}, path)
    return path


def test_student_h1_is_the_longer_lego_h_row_and_no_ablation_seed(tmp_path):
    """``student_h1.pt`` is the row ``h1_lego_h_long`` when trained with HLM; the ablation rows
    (LEGO-H, w TC-ViT) never take it, whatever it holds, and each row records its env steps."""
    fake_checkpoint(tmp_path / "student_h1.pt", student_meta(), hlm_config(False), frames=10_752_000)
    long = pt.resolve_row(pt.ROWS["h1_lego_h_long"], tmp_path)
    assert not long.found and long.path == tmp_path / "student_h1.pt"
    assert long.note == f"{tmp_path / 'student_h1.pt'} holds the H1 student (tcvit, HLM off): HLM off, the row needs HLM on"
    for key in ("h1_lego_h", "h1_no_hlm"):  # HLM off: still not the w TC-ViT row
        res = pt.resolve_row(pt.ROWS[key], tmp_path)
        assert (res.found, res.path, res.note) == (False, tmp_path / "ablations" / f"{key}.pt", "")
    fake_checkpoint(tmp_path / "ablations" / "h1_no_hlm.pt", student_meta(), hlm_config(False), frames=1_699_584)
    no_hlm = pt.resolve_row(pt.ROWS["h1_no_hlm"], tmp_path)
    assert no_hlm.paths == (tmp_path / "ablations" / "h1_no_hlm.pt",) and no_hlm.frames == (1_699_584,)
    fake_checkpoint(tmp_path / "student_h1.pt", student_meta(), hlm_config(True), frames=10_752_000)
    long = pt.resolve_row(pt.ROWS["h1_lego_h_long"], tmp_path)
    assert long.found and long.paths == (tmp_path / "student_h1.pt",) and long.frames == (10_752_000,)
    assert not pt.resolve_row(pt.ROWS["h1_lego_h"], tmp_path).found
    fake_checkpoint(tmp_path / "ablations" / "h1_lego_h_seed0.pt", student_meta(), hlm_config(True))  # frames unrecorded
    lego = pt.resolve_row(pt.ROWS["h1_lego_h"], tmp_path)
    assert lego.paths == (tmp_path / "ablations" / "h1_lego_h_seed0.pt",) and lego.frames == (None,)
    missing = pt.resolve_row(pt.ROWS["h1_rmab"], tmp_path)
    assert (missing.found, missing.path, missing.note) == (False, tmp_path / "ablations" / "h1_rmab.pt", "")


def test_the_converged_rows_take_the_stage5_student_and_their_own_seeds_only(tmp_path):
    """Table 1 at convergence: LEGO-H is ``student_h1_real_pits.pt`` (seed 0, the run the others
    branch from) and the
    ``h1_lego_h_converged`` seeds; w TC-ViT and Vanilla their own seeds; the 1.70M-step rows take
    none of these files and the converged rows none of theirs."""
    fake_checkpoint(tmp_path / "student_h1_real_pits.pt", student_meta(), hlm_config(True), frames=6_912_000)
    fake_checkpoint(tmp_path / "student_h1.pt", student_meta(), hlm_config(True), frames=4_608_000)  # not a seed
    fake_checkpoint(tmp_path / "ablations" / "h1_lego_h_converged_seed1.pt", student_meta(), hlm_config(True),
                    frames=6_912_000)
    fake_checkpoint(tmp_path / "ablations" / "h1_no_hlm_converged_seed0.pt", student_meta(), hlm_config(False),
                    frames=6_912_000)
    fake_checkpoint(tmp_path / "ablations" / "h1_no_hlm_seed1.pt", student_meta(), hlm_config(False),
                    frames=1_699_584)
    fake_checkpoint(tmp_path / "ablations" / "h1_vanilla_converged_seed0.pt", student_meta(perception="vanilla"),
                    hlm_config(False), frames=6_912_000)
    lego = pt.resolve_row(pt.ROWS["h1_lego_h_converged"], tmp_path)
    assert lego.paths == (tmp_path / "student_h1_real_pits.pt", tmp_path / "ablations" / "h1_lego_h_converged_seed1.pt")
    assert lego.frames == (6_912_000, 6_912_000)
    no_hlm = pt.resolve_row(pt.ROWS["h1_no_hlm_converged"], tmp_path)
    assert no_hlm.paths == (tmp_path / "ablations" / "h1_no_hlm_converged_seed0.pt",)
    assert pt.resolve_row(pt.ROWS["h1_no_hlm"], tmp_path).paths == (tmp_path / "ablations" / "h1_no_hlm_seed1.pt",)
    assert not pt.resolve_row(pt.ROWS["h1_lego_h"], tmp_path).found
    vanilla = pt.resolve_row(pt.ROWS["h1_vanilla_converged"], tmp_path)
    assert vanilla.paths == (tmp_path / "ablations" / "h1_vanilla_converged_seed0.pt",)
    assert not pt.resolve_row(pt.ROWS["h1_vanilla"], tmp_path).found
    # a w TC-ViT file trained with HLM is not the row
    fake_checkpoint(tmp_path / "ablations" / "h1_no_hlm_converged_seed1.pt", student_meta(), hlm_config(True))
    res = pt.resolve_row(pt.ROWS["h1_no_hlm_converged"], tmp_path)
    assert res.paths == (tmp_path / "ablations" / "h1_no_hlm_converged_seed0.pt",)
    assert "h1_no_hlm_converged_seed1.pt holds the H1 student (tcvit, HLM on)" in res.note


# ---------------------------------------------------------------------------------------------
# tables from hand-made results


def aggregate_of(success: float, groups=("randommix",)) -> dict:
    row = {"success": (success, 1.0), "trail_completion": (40.0, 2.0), "traverse_rate": (60.0, 0.5),
           "mev": (5.0, 0.25), "ttf": (12.0, 0.5), "time_to_reach": (math.nan, math.nan)}
    return {**{g: dict(row) for g in groups}, "overall": row}


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_tables_put_the_paper_under_ours_and_list_rows_not_trained(tmp_path):
    ck = Path("ck")
    results = {
        "h1_oracle": pt.RowResult("h1_oracle", "evaluated", ck / "oracle_h1.pt", rows=aggregate_of(50.0),
                                  frames=(13_676_544,)),
        "h1_lego_h": pt.RowResult("h1_lego_h", "not trained", ck / "student_h1.pt",
                                  "ck/student_h1.pt holds the H1 student (tcvit, HLM off): HLM off, the row needs HLM on"),
        "h1_no_hlm": pt.RowResult("h1_no_hlm", "evaluated", ck / "ablations/h1_no_hlm_seed1.pt", rows=aggregate_of(25.5),
                                  paths=(ck / "ablations/h1_no_hlm_seed1.pt", ck / "ablations/h1_no_hlm_seed2.pt"),
                                  frames=(1_699_584, 1_720_000)),
        "h1_vanilla": pt.RowResult("h1_vanilla", "failed", ck / "ablations/h1_vanilla.pt", "ValueError: bad"),
        "h1_eph": pt.RowResult("h1_eph", "evaluated", ck / "ablations/h1_eph.pt", rows=aggregate_of(10.0)),
        "h1_rmab": pt.RowResult("h1_rmab", "not trained", ck / "ablations/h1_rmab.pt"),
    }
    tables = [pt.TABLES["ablation"], pt.TABLES["terrains"]]
    written = pt.write_tables(tables, results, tmp_path, "# header\n\nTrail seeds: 1, 2")
    assert set(written) == {"ablation.md", "ablation.csv", "terrains.md", "terrains.csv", "tables.md"}
    md = (tmp_path / "ablation.md").read_text()
    lines = md.splitlines()
    assert ("| method | source | env steps | SR (%) ↑ | TC (%) ↑ | TR (%) ↑ | MEV (%) ↓ | TTF (s) ↑ | T2R (s) ↓ "
            "| checkpoint |") in lines
    oracle = lines.index("| Oracle | ours | 13.68M | 50.00 ± 1.00 | 40.00 ± 2.00 | 60.00 ± 0.50 | 5.00 ± 0.25 "
                         "| 12.00 ± 0.50 | n/a | `ck/oracle_h1.pt` |")
    assert lines[oracle + 1] == ("|  | paper |  | 71.20 ± 0.72 | 77.73 ± 0.92 | 73.60 ± 0.81 | 7.12 ± 0.92 "
                                 "| 7.25 ± 0.09 | 4.59 ± 0.08 |  |")
    lego = next(ln for ln in lines if ln.startswith("| LEGO-H | ours |"))
    assert lego.startswith("| LEGO-H | ours | — | not trained | — | — | — | — | — |")
    assert "not trained: `ck/student_h1.pt`; ck/student_h1.pt holds" in lego
    assert any(ln.startswith("| w TC-ViT (no HLM) | ours | 1.70M-1.72M | 25.50 ± 1.00 |") for ln in lines)
    assert any(ln.startswith("| Vanilla (ConvGRU) | ours | — | failed |") and "ValueError: bad" in ln for ln in lines)
    rows = read_csv(tmp_path / "ablation.csv")
    assert [(r["method"], r["source"], r["status"]) for r in rows] == [
        ("Oracle", "ours", "evaluated"), ("Oracle", "paper", "paper"),
        ("LEGO-H", "ours", "not trained"), ("LEGO-H", "paper", "paper"),
        ("w TC-ViT (no HLM)", "ours", "evaluated"), ("w TC-ViT (no HLM)", "paper", "paper"),
        ("Vanilla (ConvGRU)", "ours", "failed"), ("Vanilla (ConvGRU)", "paper", "paper")]
    assert float(rows[0]["success_mean"]) == 50.0 and float(rows[0]["mev_std"]) == 0.25
    assert rows[0]["checkpoint"] == "ck/oracle_h1.pt" and rows[0]["time_to_reach_mean"] == "nan"
    assert (rows[0]["env_steps"], rows[1]["env_steps"], rows[4]["env_steps"]) == ("13676544", "", "1699584;1720000")
    assert (rows[1]["success_mean"], rows[1]["success_std"]) == ("71.2", "0.72")
    assert rows[2]["success_mean"] == "" and rows[2]["checkpoint"] == "ck/student_h1.pt" and "HLM off" in rows[2]["note"]
    terrains = read_csv(tmp_path / "terrains.csv")
    eph = [r for r in terrains if r["method"] == "EP-H" and r["source"] == "ours"]
    assert [(r["trails"], r["status"]) for r in eph] == [("randommix", "evaluated")] + [
        (c, "not evaluated") for c in ("ditch", "hurdle", "gap", "forest")]
    assert all(r["status"] == "not trained" for r in terrains if r["method"] == "RMA-B" and r["source"] == "ours")
    assert "| EP-H | randommix | ours | — | 10.00 ± 1.00 |" in (tmp_path / "terrains.md").read_text()
    everything = (tmp_path / "tables.md").read_text()
    assert everything.startswith("# header\n\nTrail seeds: 1, 2\n") and md in everything
    assert "| h1_lego_h | LEGO-H (tab:ablation_h1) | not trained | `ck/student_h1.pt` |" in everything


def test_paper_only_tables_have_no_rows_of_ours(tmp_path):
    pt.write_tables([pt.TABLES["g1"]], None, tmp_path, "# paper")
    lines = (tmp_path / "g1.md").read_text().splitlines()
    assert "| G1 (LEGO-H) | paper | 63.96 ± 1.03 | 38.94 ± 0.63 | 62.21 ± 0.97 | 5.33 ± 0.68 | 7.24 ± 0.22 | 8.10 ± 0.08 |" in lines
    assert not any("ours" in ln or "G1 oracle" in ln for ln in lines if ln.startswith("|"))
    assert {r["source"] for r in read_csv(tmp_path / "g1.csv")} == {"paper"}


def test_each_checkpoint_is_evaluated_once_and_a_failure_does_not_stop_the_others(tmp_path):
    fake_checkpoint(tmp_path / "student_h1.pt", student_meta(), hlm_config(True))
    fake_checkpoint(tmp_path / "oracle_h1.pt", {"robot": "h1", "kind": "oracle"})
    calls = []

    def fake_evaluate(path, settings, out):
        calls.append((path.name, out.name))
        if path.name == "oracle_h1.pt":
            raise RuntimeError("diverged")
        return aggregate_of(42.0)

    keys = [r.key for name in ("ablation", "g1", "hlm_vae", "gru_ct") for r in pt.TABLES[name].rows]
    results = pt.run_rows(keys, tmp_path, pt.Settings((1, 2)), tmp_path / "out", evaluate_fn=fake_evaluate)
    assert calls == [("oracle_h1.pt", "oracle_h1"), ("student_h1.pt", "student_h1")]
    long = results["h1_lego_h_long"]
    assert long.status == "evaluated" and long.rows["overall"]["success"] == (42.0, 1.0)
    assert results["h1_oracle"].status == "failed" and results["h1_oracle"].note == "RuntimeError: diverged"
    for key in ("h1_lego_h", "h1_no_hlm"):  # the ablation rows: nothing under ablations/
        assert (results[key].status, results[key].note) == ("not trained", "")
    assert results["h1_ct"].status == "not trained" and results["h1_ct"].path == tmp_path / "ablations" / "h1_ct.pt"
    assert list(results) == list(dict.fromkeys(keys))


# ---------------------------------------------------------------------------------------------
# the command line


@pytest.mark.parametrize("argv, message", [
    (["--trail-seeds", "1", "--tables", "ablation", "nope"], "unknown table 'nope'; valid: ['ablation', "),
    (["--trail-seeds", "1", "--tables", "g1", "g1"], "tables must be distinct, got ['g1', 'g1'] (repeated: ['g1'])"),
    (["--trail-seeds", "3", "4", "3"], "trail_seeds must be a non-empty list of distinct seeds, got [3, 4, 3]"),
    (["--tables", "g1"], "--trail-seeds is required"),
    (["--trail-seeds"], "expected at least one argument"),
    (["--trail-seeds", "1", "--robots-per-cell", "0"], "robots_per_cell and runs must be >= 1, got 0, 1"),
    (["--trail-seeds", "1", "--levels", "0", "0"], "levels must be distinct, got [0, 0] (repeated: [0])"),
    (["--trail-seeds", "1", "--variants", "-2"], "variants must be >= 1, got -2"),
    (["--trail-seeds", "1", "--protocol", "gpu"], "unknown protocol 'gpu'; valid: ['cpu', 'paper']"),
    (["--trail-seeds", "1", "--categories", "randommix", "swamp"], "unknown categories ['swamp']"),
    (["--trail-seeds", "1", "--levels", "0", "7"], "levels [7] out of range; valid: 0..4"),
    (["--trail-seeds", "1", "--checkpoints", "/nonexistent/ck"], "--checkpoints '/nonexistent/ck' is not a folder"),
    (["--trail-seeds", "1", "--domain-rand", "--into", "RESULTS.md"],
     "--domain-rand with --into ['RESULTS.md']: the marked tables are the nominal benchmark's"),
])
def test_bad_command_lines_are_refused_naming_the_bad_value(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        recipe.main(argv)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


def test_only_paper_writes_every_table_without_evaluating(tmp_path, monkeypatch):
    monkeypatch.setattr(pt, "run_rows", lambda *a, **k: pytest.fail("--only-paper evaluated something"))
    assert recipe.main(["--only-paper", "--out", str(tmp_path)]) == 0
    assert {p.name for p in tmp_path.iterdir()} == {f"{n}.{ext}" for n in pt.TABLES for ext in ("md", "csv")} | {"tables.md"}
    text = (tmp_path / "tables.md").read_text()
    assert "Command: `python recipes/paper_tables.py --only-paper --out" in text
    assert "| Oracle | paper | 71.20 ± 0.72 |" in text


def test_the_committed_oracle_end_to_end_on_a_tiny_protocol(tmp_path, capsys, monkeypatch):
    ck = tmp_path / "ck"
    ck.mkdir()
    (ck / "oracle_h1.pt").symlink_to(ROOT / "checkpoints" / "oracle_h1.pt")
    out = tmp_path / "tables"
    argv = ["--checkpoints", str(ck), "--out", str(out), "--trail-seeds", "9101", "--robots-per-cell", "1",
            "--variants", "1", "--categories", "randommix", "--levels", "0", "--tables", "ablation",
            "--num-threads", "1", "--device", "cpu"]
    assert recipe.main(argv) == 0
    assert {p.name for p in out.iterdir()} == {"ablation.md", "ablation.csv", "tables.md", "evals"}
    assert (out / "evals" / "oracle_h1" / "table.md").is_file()
    rows = {(r["row"], r["source"]): r for r in read_csv(out / "ablation.csv")}
    oracle = rows[("h1_oracle", "ours")]
    assert oracle["status"] == "evaluated" and oracle["checkpoint"] == str(ck / "oracle_h1.pt")
    assert 0.0 <= float(oracle["success_mean"]) <= 100.0 and float(oracle["ttf_mean"]) > 0.0
    assert float(oracle["success_std"]) == 0.0  # one trail grid, one run
    for key in ("h1_lego_h", "h1_no_hlm", "h1_vanilla"):
        assert rows[(key, "ours")]["status"] == "not trained" and rows[(key, "ours")]["success_mean"] == ""
    assert rows[("h1_no_hlm", "ours")]["checkpoint"] == str(ck / "ablations" / "h1_no_hlm.pt")
    text = (out / "tables.md").read_text()
    assert "Trail seeds: 9101" in text and "--trail-seeds 9101" in text
    assert f"not trained: `{ck / 'ablations' / 'h1_lego_h.pt'}`" in text
    assert "| Oracle | ours | " in capsys.readouterr().out
    record = json.loads((out / "evals" / "oracle_h1" / eval_run.RECORD_NAME).read_text())
    assert record["checkpoint_sha256"] == hashlib.sha256((ROOT / "checkpoints" / "oracle_h1.pt").read_bytes()).hexdigest()
    assert record["config"]["trail_seeds"] == [9101] and "output_dir" not in record["config"]
    # the same command again reads the evaluation back; --fresh or another protocol evaluates again
    before = (out / "ablation.csv").read_text()
    calls = []

    def fake_evaluate(cfg):
        calls.append(cfg.robots_per_cell)
        return {"rows": {"overall": {m: (1.0, 0.0) for m in pt.METRICS}}}

    monkeypatch.setattr(eval_run, "evaluate", fake_evaluate)
    assert recipe.main(argv) == 0 and calls == []
    assert (out / "ablation.csv").read_text() == before
    assert recipe.main(argv + ["--fresh"]) == 0 and calls == [1]
    assert recipe.main(argv) == 0 and calls == [1]  # the record is now the fresh evaluation's
    assert recipe.main(argv + ["--robots-per-cell", "2"]) == 0 and calls == [1, 2]
    # an evaluate.py run made on its own (its record written by evaluate.py) is taken up with
    # --reuse-from by a new --out, on the same protocol only
    alone = tmp_path / "alone"
    monkeypatch.undo()
    with initialize_config_dir(config_dir=str(eval_run.CONFIG_DIR), version_base=None):
        cfg = compose(config_name="evaluate", overrides=[
            f"checkpoint={ck / 'oracle_h1.pt'}", "trail_seeds=[9101]", "robots_per_cell=1", "variants=1",
            "categories=[randommix]", "levels=[0]", "video=false", "num_threads=1", "device=cpu",
            f"output_dir={alone / 'oracle'}", "logger.backend=csv"])
    eval_run.evaluate(cfg)  # the real evaluate.py, as its command line runs it
    assert json.loads((alone / "oracle" / eval_run.RECORD_NAME).read_text())["checkpoint_sha256"] == record["checkpoint_sha256"]
    monkeypatch.setattr(eval_run, "evaluate", fake_evaluate)
    fresh_out = ["--out", str(tmp_path / "tables2")]
    assert recipe.main(argv + fresh_out + ["--reuse-from", str(alone)]) == 0 and calls == [1, 2]
    assert recipe.main(argv + ["--out", str(tmp_path / "tables3"), "--reuse-from", str(alone), "--variants", "2"]) == 0
    assert calls == [1, 2, 1]  # another protocol: evaluated, not taken up
    # under the training's randomisation: evaluated with domain_rand, not taken up from a nominal evaluation
    dr_cfgs = []
    monkeypatch.setattr(eval_run, "evaluate", lambda cfg: dr_cfgs.append(cfg) or fake_evaluate(cfg))
    dr_out = tmp_path / "tables_dr"
    assert recipe.main(argv + ["--out", str(dr_out), "--reuse-from", str(alone), str(out), "--domain-rand"]) == 0
    assert len(dr_cfgs) == 1 and dr_cfgs[0].domain_rand is True
    assert json.loads((dr_out / "evals" / "oracle_h1" / eval_run.RECORD_NAME).read_text())["config"]["domain_rand"] is True
    assert "under the training's domain randomisation" in (dr_out / "tables.md").read_text()


def test_an_archive_keeps_each_evaluation_so_a_new_checkout_refills_without_evaluating(tmp_path, monkeypatch):
    """--archive DIR: each evaluation's record and table.csv are kept in DIR/<name>-<digest>/ and
    taken up from there by a later run with an empty --out; another protocol or a changed
    checkpoint file is evaluated again and kept beside."""
    ck = tmp_path / "ck"
    fake_checkpoint(ck / "student_h1.pt", student_meta(), hlm_config(True))
    fake_checkpoint(ck / "oracle_g1_trails.pt", {"robot": "g1", "kind": "oracle"})
    calls = []

    def fake_evaluate(cfg):  # writes table.csv as evaluate.py does
        calls.append(Path(cfg.checkpoint).name)
        rows = aggregate_of(30.0 + len(calls))
        eval_run.write_csv(rows, Path(cfg.output_dir) / "table.csv")
        return {"rows": rows}

    monkeypatch.setattr(eval_run, "evaluate", fake_evaluate)
    archive = tmp_path / "archive"
    argv = ["--checkpoints", str(ck), "--trail-seeds", "9101", "--robots-per-cell", "1", "--variants", "1",
            "--tables", "g1", "--archive", str(archive)]
    assert recipe.main(argv + ["--out", str(tmp_path / "a")]) == 0
    assert calls == ["student_h1.pt", "oracle_g1_trails.pt"]
    kept = sorted(archive.iterdir())
    assert [re.fullmatch(r"(oracle_g1_trails|student_h1)-[0-9a-f]{12}", k.name).group(1) for k in kept] == \
        ["oracle_g1_trails", "student_h1"]
    for k in kept:
        assert {f.name for f in k.iterdir()} == {"table.csv", eval_run.RECORD_NAME}
        name = k.name.rsplit("-", 1)[0]
        assert json.loads((k / eval_run.RECORD_NAME).read_text()) == \
            json.loads((tmp_path / "a" / "evals" / name / eval_run.RECORD_NAME).read_text())
    student = {(r["row"], r["source"]): r for r in read_csv(tmp_path / "a" / "g1.csv")}[("h1_lego_h_long", "ours")]
    assert float(student["success_mean"]) == 31.0 and student["time_to_reach_mean"] == "nan"  # NaN survives
    # a fresh --out (as in a new checkout): every figure read back from the archive, none evaluated
    assert recipe.main(argv + ["--out", str(tmp_path / "b")]) == 0 and len(calls) == 2
    assert (tmp_path / "b" / "g1.csv").read_text() == (tmp_path / "a" / "g1.csv").read_text()
    # another protocol, and a checkpoint changed in place: evaluated again, kept beside the others
    assert recipe.main(argv + ["--out", str(tmp_path / "c"), "--variants", "2"]) == 0 and len(calls) == 4
    fake_checkpoint(ck / "student_h1.pt", student_meta(retrained=True), hlm_config(True))
    assert recipe.main(argv + ["--out", str(tmp_path / "d")]) == 0 and calls[4:] == ["student_h1.pt"]
    assert len(list(archive.iterdir())) == 5


@pytest.mark.slow
def test_the_committed_tables_render_again_from_the_committed_archive(tmp_path, monkeypatch):
    """RESULTS.md's command on a copy of the committed archive (docs/paper_tables/evals) writes
    docs/paper_tables/'s tables and RESULTS.md's marked tables byte for byte (tables.md but for
    its command line), reading every figure back: nothing is evaluated, the archive is unchanged."""
    archive = tmp_path / "evals"
    shutil.copytree(ROOT / "docs" / "paper_tables" / "evals", archive)
    results = tmp_path / "RESULTS.md"
    shutil.copyfile(ROOT / "RESULTS.md", results)
    out = tmp_path / "tables"

    def no_evaluation(cfg):
        raise AssertionError(f"evaluated {cfg.checkpoint}: the archive should hold it")

    monkeypatch.setattr(eval_run, "evaluate", no_evaluation)
    monkeypatch.chdir(ROOT)  # the tables name checkpoints as checkpoints/<file>
    argv = ["--trail-seeds", "7901", "7902", "7903", "--robots-per-cell", "8", "--variants", "8",
            "--archive", str(archive), "--into", str(results), "--out", str(out)]
    assert recipe.main(argv) == 0
    committed = ROOT / "docs" / "paper_tables"
    for path in sorted(committed.glob("*.csv")):
        assert (out / path.name).read_bytes() == path.read_bytes(), path.name
    command = re.compile(r"^Command: .*$", re.M)
    assert command.sub("", (out / "tables.md").read_text()) == command.sub("", (committed / "tables.md").read_text())
    assert results.read_bytes() == (ROOT / "RESULTS.md").read_bytes()
    copied = filecmp.dircmp(archive, committed / "evals")
    assert not (copied.left_only or copied.right_only or copied.diff_files)
    assert all(not (d.left_only or d.right_only or d.diff_files) for d in copied.subdirs.values())


def test_a_row_with_several_training_seeds_is_their_mean_and_std(tmp_path):
    """Every matching candidate is a training seed (globs expanded in name order); the row is the
    mean ± std over the seeds' own means; one failed seed fails the row; CSV and markdown name
    every checkpoint."""
    fake_checkpoint(tmp_path / "student_h1.pt", student_meta(), hlm_config(True))  # the longer run: not a seed
    for seed in (0, 1, 2):
        fake_checkpoint(tmp_path / "ablations" / f"h1_lego_h_seed{seed}.pt", student_meta(), hlm_config(True))
        if seed:
            fake_checkpoint(tmp_path / "ablations" / f"h1_no_hlm_seed{seed}.pt", student_meta(), hlm_config(False))
    fake_checkpoint(tmp_path / "ablations" / "h1_no_hlm_seed3.pt", student_meta(), hlm_config(True))  # HLM on: not a seed
    lego = pt.resolve_row(pt.ROWS["h1_lego_h"], tmp_path)
    assert lego.paths == tuple(tmp_path / "ablations" / f"h1_lego_h_seed{seed}.pt" for seed in (0, 1, 2))
    no_hlm = pt.resolve_row(pt.ROWS["h1_no_hlm"], tmp_path)
    assert [p.name for p in no_hlm.paths] == ["h1_no_hlm_seed1.pt", "h1_no_hlm_seed2.pt"]
    assert "h1_no_hlm_seed3.pt holds the H1 student (tcvit, HLM on)" in no_hlm.note
    success = {"h1_lego_h_seed0": 50.0, "h1_lego_h_seed1": 56.0, "h1_lego_h_seed2": 59.0,
               "h1_no_hlm_seed1": 40.0, "h1_no_hlm_seed2": 44.0}

    def fake_evaluate(path, settings, out):
        agg = aggregate_of(success[path.stem])
        agg["overall"] = {**agg["overall"], "time_to_reach": (math.nan, math.nan) if "seed1" in path.stem
                          else (10.0 + success[path.stem], 0.0)}
        return agg

    results = pt.run_rows(["h1_lego_h", "h1_no_hlm"], tmp_path, pt.Settings((1,)), tmp_path / "out",
                          evaluate_fn=fake_evaluate)
    lego_sr = results["h1_lego_h"].rows["overall"]["success"]
    assert lego_sr == pytest.approx((55.0, math.sqrt(((50 - 55) ** 2 + 1 + 16) / 3)))
    assert results["h1_no_hlm"].rows["overall"]["success"] == pytest.approx((42.0, 2.0))
    assert results["h1_no_hlm"].rows["overall"]["time_to_reach"] == pytest.approx((54.0, 0.0))  # the NaN seed left out
    assert [a["overall"]["success"][0] for a in results["h1_lego_h"].per_seed] == [50.0, 56.0, 59.0]
    md = pt.markdown(pt.TABLES["ablation"], results)
    assert "`" + str(tmp_path / "ablations" / "h1_no_hlm_seed2.pt") + "` (2 training seeds: mean ± std over seeds)" in md
    assert "42.00 ± 2.00" in md
    rec = next(r for r in pt.csv_rows(pt.TABLES["ablation"], results) if r["row"] == "h1_no_hlm" and r["source"] == "ours")
    assert rec["checkpoint"].split(";") == [str(p) for p in no_hlm.paths] and rec["success_mean"] == pytest.approx(42.0)

    def one_fails(path, settings, out):
        if path.stem == "h1_no_hlm_seed2":
            raise RuntimeError("diverged")
        return fake_evaluate(path, settings, out)

    failed = pt.run_rows(["h1_no_hlm"], tmp_path, pt.Settings((1,)), tmp_path / "out2", evaluate_fn=one_fails)
    assert failed["h1_no_hlm"].status == "failed" and "h1_no_hlm_seed2.pt: RuntimeError: diverged" in failed["h1_no_hlm"].note


def test_tables_go_between_their_markers_and_nothing_else_changes():
    text = ("# Results\n\nintro\n<!-- paper_tables:ablation -->\nold rows\n<!-- /paper_tables:ablation -->\n"
            "between\n<!-- paper_tables:g1 -->\nkept\n<!-- /paper_tables:g1 -->\nend\n")
    new, filled = pt.fill_markers(text, {"ablation": "### Ablation (`tab:ablation_h1`)\n\n| a |\n|---|\n| 1 |\n"})
    assert filled == ["ablation"]
    assert new == ("# Results\n\nintro\n<!-- paper_tables:ablation -->\n| a |\n|---|\n| 1 |\n"
                   "<!-- /paper_tables:ablation -->\nbetween\n<!-- paper_tables:g1 -->\nkept\n"
                   "<!-- /paper_tables:g1 -->\nend\n")
    again, _ = pt.fill_markers(new, {"ablation": "### Ablation (`tab:ablation_h1`)\n\n| a |\n|---|\n| 1 |\n"})
    assert again == new  # filling twice changes nothing


@pytest.mark.parametrize("text, message", [
    ("<!-- paper_tables:tabel1 -->\nx\n<!-- /paper_tables:tabel1 -->\n", "marker <!-- paper_tables:tabel1 --> names no table"),
    ("<!-- paper_tables:g1 -->\nx\n", "marker <!-- paper_tables:g1 --> has no closing"),
    ("<!-- paper_tables:g1 -->\nx\n<!-- /paper_tables:ablation -->\n", "marker <!-- paper_tables:g1 --> has no closing"),
    ("<!-- paper_tables:g1 -->\n<!-- /paper_tables:g1 -->\n<!-- paper_tables:g1 -->\n<!-- /paper_tables:g1 -->\n",
     "marked tables must be distinct"),
])
def test_bad_markers_are_refused_naming_the_marker(text, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        pt.fill_markers(text, {})


def test_into_writes_the_tables_into_a_results_file_and_checks_it_first(tmp_path, capsys):
    results = tmp_path / "RESULTS.md"
    results.write_text("top\n<!-- paper_tables:hlm_vae -->\n<!-- /paper_tables:hlm_vae -->\nbottom\n")
    assert recipe.main(["--only-paper", "--tables", "hlm_vae", "--out", str(tmp_path / "t"), "--into", str(results)]) == 0
    text = results.read_text()
    assert text.startswith("top\n<!-- paper_tables:hlm_vae -->\n") and text.endswith("<!-- /paper_tables:hlm_vae -->\nbottom\n")
    assert "| Vanilla VAE | paper | 53.49 ± 1.61 |" in text and "###" not in text
    results.write_text("<!-- paper_tables:hlm_vae -->\n")  # refused before anything is evaluated
    with pytest.raises(SystemExit):
        recipe.main(["--trail-seeds", "1", "--out", str(tmp_path / "t"), "--into", str(results)])
    assert f"{results}: marker <!-- paper_tables:hlm_vae --> has no closing" in capsys.readouterr().err


def test_contrasts_report_the_difference_welch_t_and_cohen_d_by_hand():
    """A table's contrast: row a - row b in SR over the training seeds, Welch's t and Cohen's d
    (sample variances) by hand; one seed on a side gives no t; a row not evaluated, no figure."""
    def seeds(*sr):
        return [aggregate_of(s) for s in sr]

    a = pt.RowResult("h1_lego_h", "evaluated", Path("a.pt"), per_seed=seeds(50.0, 54.0, 58.0))
    b = pt.RowResult("h1_no_hlm", "evaluated", Path("b.pt"), per_seed=seeds(50.0, 50.0, 53.0))
    c = render.contrast(a, b)  # means 54 and 51; variances 16 and 3
    assert c["diff"] == pytest.approx(3.0) and (c["n_a"], c["n_b"]) == (3, 3)
    assert c["t"] == pytest.approx(3.0 / math.sqrt(16 / 3 + 3 / 3))
    assert c["d"] == pytest.approx(3.0 / math.sqrt((16 + 3) / 2))
    one = pt.RowResult("h1_vanilla", "evaluated", Path("v.pt"), per_seed=seeds(40.0))
    assert render.contrast(b, one) == {"diff": pytest.approx(11.0), "t": None, "d": None, "n_a": 3, "n_b": 1}
    assert render.contrast(a, pt.RowResult("h1_no_hlm", "not trained", Path("b.pt"))) is None
    results = {"h1_oracle": pt.RowResult("h1_oracle", "evaluated", Path("o.pt"), rows=aggregate_of(80.0)),
               "h1_lego_h": a, "h1_no_hlm": b}
    text = pt.markdown(pt.TABLES["ablation"], results)
    assert ("- HLM (LEGO-H - w TC-ViT (no HLM)), SR points: ours +3.00 (3 vs 3 training seeds, "
            f"Welch's t = {3.0 / math.sqrt(16 / 3 + 1):.2f}, Cohen's d = {3.0 / math.sqrt(9.5):.2f}); "
            "paper +3.67") in text
    assert ("- TC-ViT over a ConvGRU (w TC-ViT (no HLM) - Vanilla (ConvGRU)), SR points: ours — "
            "(a row not evaluated); paper +21.76") in text
