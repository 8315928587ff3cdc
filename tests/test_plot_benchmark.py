"""recipes/plot_benchmark.py: evaluation tables read as curve points, the figure, bad input."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))

import plot_benchmark  # noqa: E402


def table(path: Path, success: float, completion: float, std: float = 1.5) -> Path:
    """A table.csv as recipes/evaluate.py writes it: per-category rows, then the overall ones."""
    rows = ["category,metric,mean,std", "ditch,success,10.0,2.0", "ditch,trail_completion,20.0,1.0",
            f"overall,success,{success},{std}", f"overall,trail_completion,{completion},{std * 2}",
            "overall,mev,6.0,0.1"]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_point_is_the_overall_rows_and_the_frames_of_the_name(tmp_path):
    path = table(tmp_path / "student_h1_frames004300800_grids9701-9703.csv", 56.5, 54.25)
    frames, point = plot_benchmark.read_point(path)
    assert frames == 4_300_800
    assert point == {"success": (56.5, 1.5), "trail_completion": (54.25, 3.0)}
    assert plot_benchmark.read_point(path, frames=7)[0] == 7


def test_missing_frames_or_rows_name_the_file(tmp_path):
    nameless = table(tmp_path / "table.csv", 50.0, 50.0)
    with pytest.raises(ValueError, match=r"table\.csv: no 'frames<digits>'"):
        plot_benchmark.read_point(nameless)
    partial = tmp_path / "x_frames000001000.csv"
    partial.write_text("category,metric,mean,std\noverall,success,40.0,1.0\n")
    with pytest.raises(ValueError, match=r"x_frames000001000\.csv: no 'overall,trail_completion' row"):
        plot_benchmark.read_point(partial)


def test_the_figure_has_hours_panels_with_rates(tmp_path):
    raw = [table(tmp_path / f"raw_frames{f:09d}.csv", sr, sr - 3) for f, sr in ((1_000_000, 40.0), (2_000_000, 50.0))]
    ema = [table(tmp_path / "ema_frames002000000.csv", 53.0, 50.0)]
    out = plot_benchmark.main(["--series", "raw", *map(str, raw), "--series", "ema", *map(str, ema),
                               "--rate", "775", "775", "--reference", "54.67", "committed",
                               "-o", str(tmp_path / "curve.png")])
    assert out.stat().st_size > 10_000
    fig_axes = plot_benchmark.plot({"raw": [plot_benchmark.read_point(p) for p in raw]}, tmp_path / "one.png")
    assert fig_axes.exists()


@pytest.mark.parametrize("argv, message", [
    (["--series", "only-a-label"], "needs a label and at least one table.csv"),
    (["--series", "a", "X", "--rate", "1", "2"], "one entry per series (1)"),
    (["--series", "a", "X", "--rate", "-5"], "positive env steps/s or a run directory, got -5"),
    (["--series", "a", "X", "--rate", "no/such/run"], "--rate no/such/run: no metrics.jsonl there"),
    (["--series", "a", "X", "--series", "a", "Y"], "labels must differ"),
])
def test_bad_arguments_are_refused_by_name(tmp_path, argv, message, capsys):
    with pytest.raises(SystemExit):
        plot_benchmark.main([*argv, "-o", str(tmp_path / "x.png")])
    assert message in capsys.readouterr().err


def test_a_run_directory_places_each_snapshot_at_the_runs_own_hours(tmp_path):
    """Hours from the run's log: the iterations' seconds summed up to the snapshot's env steps,
    not env steps over an average rate (a run's early iterations may be faster than its mean)."""
    run = tmp_path / "run"
    run.mkdir()
    rows = [{"step": 100, "train/iteration_s": 900.0}, {"step": 200, "train/iteration_s": 900.0},
            {"step": 300, "train/iteration_s": 3600.0}]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    hours = plot_benchmark.run_hours(run)
    assert plot_benchmark.hours_of([200, 300], hours) == [0.5, 1.5]
    assert plot_benchmark.hours_of([1800, 3600], 1.0) == [0.5, 1.0]  # a rate: env steps / (steps/s) / 3600
    with pytest.raises(ValueError, match=r"metrics\.jsonl: no iteration ended at 250 env steps"):
        hours(250)
    points = [table(tmp_path / f"s_frames{f:09d}.csv", 50.0, 40.0) for f in (100, 300)]
    out = plot_benchmark.main(["--series", "s", *map(str, points), "--rate", str(run), "-o", str(tmp_path / "h.png")])
    assert out.stat().st_size > 10_000
