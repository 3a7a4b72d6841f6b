"""``railstop report DIR --csv``: each campaign's runs as CSV beside its Parquet (issue 38)."""

from __future__ import annotations

import csv
import math
import subprocess
from pathlib import Path

import pyarrow.parquet as pq

from zygote import run_cli


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=cwd)  # forked from a warm zygote (tests/zygote.py)


def test_the_csv_holds_every_run_and_column_of_the_parquet(tmp_path: Path) -> None:
    r = run("campaign", "--runs", "30", "--out", "c", "--db", "c.db", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = run("report", "c", "--csv", "--worst", "0", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "runs as CSV: c/runs.csv" in r.stdout
    table = pq.read_table(tmp_path / "c" / "runs.parquet")
    with (tmp_path / "c" / "runs.csv").open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == table.num_rows == 30
    assert list(rows[0]) == table.column_names
    errors = table.column("stop_error_m").to_pylist()
    for row, want in zip(rows, errors, strict=True):
        got = float(row["stop_error_m"])
        assert (math.isnan(got) and math.isnan(want)) or got == want  # the same numbers, exactly
