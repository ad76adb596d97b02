"""The benchmark's quick mode runs end to end and writes its tables and plot."""
from __future__ import annotations

import csv

import numpy as np

from mvm.eval.bench import COLUMNS, TABLE1, TABLE2, markdown_table, run_bench

from helpers import standing_poses


def test_quick_bench_tables_and_files(tmp_path):
    from mvm.eval.bench_files import write_bench_report

    result = run_bench(quick=True, bank_poses=standing_poses())
    assert [r["method"] for r in result.table1] == [m.label for m in TABLE1]
    assert [r["method"] for r in result.table2] == [m.label for m in TABLE2]
    assert result.table1_short[0]["method"].startswith("Dong") and result.table1_short[0]["clips"] == 2
    mvm = next(r for r in result.table1 if r["method"].startswith("MVM"))
    hungarian = result.table1[0]
    assert mvm["f1"] >= 0.9 and mvm["recovered"] == 1.0
    assert mvm["mpjpe_mm"] < 50
    assert hungarian["recall"] < mvm["recall"]             # sequential matching fragments tracks
    for row in result.rows:
        assert 0 <= row["precision"] <= 1 and row["matching_s"] > 0
    assert {r["axis"] for r in result.sweep_rows} == {"parallax_deg", "people", "detector"}
    path = write_bench_report(result, tmp_path, "mvm bench --quick", 1.0)
    text = path.read_text()
    assert "Table 1" in text and "Table 2" in text and "Sweep of parallax_deg" in text
    with open(tmp_path / "clips.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(result.rows) and "mpjpe_mm" in rows[0]
    assert (tmp_path / "matching_time.png").read_bytes()[:4] == b"\x89PNG"


def test_markdown_table_formats_missing_values():
    text = markdown_table([{"method": "x", "clips": 2, "E_R_px": float("nan"), "f1": 0.5}],
                          [("method", "method", 0), ("clips", "clips", 0), ("E_R_px", "E_R", 1), ("f1", "F1", 3)])
    assert text.splitlines()[2] == "| x | 2 | – | 0.500 |"
    assert len(COLUMNS) == len({c[0] for c in COLUMNS})
    assert np.isfinite(0.0)


def test_cli_commands(tmp_path):
    from click.testing import CliRunner

    from mvm.cli.sim import simulate_cmd

    result = CliRunner().invoke(simulate_cmd, [str(tmp_path / "s"), "--people", "2", "--frames", "20",
                                               "--preset", "hard", "--seed", "1"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "s" / "poses2d.json").is_file() and (tmp_path / "s.groundtruth.json").is_file()
    bad = CliRunner().invoke(simulate_cmd, [str(tmp_path / "t"), "--people", "0"])
    assert bad.exit_code == 2 and "people" in bad.output
