"""``benchmarks/forms_standard.py`` on a few runs: a row per (form, controller), shares that are
shares, misses counted once, and refused arguments in one line."""

from __future__ import annotations

import re

import pytest

from bench_loader import load_benchmark

bench = load_benchmark("forms_standard")

ROW = re.compile(
    r"^\s+(?P<form>\d) (?P<ctrl>\S+)\s+(?P<p30>[\d.]+)%\s+(?P<ptol>[\d.]+)%"
    r"\s+(?P<silent>\d+)\s+(?P<eb>\d+)\s+(?P<rest>.*)$"
)


def _rows(out: str) -> list[re.Match[str]]:
    return [m for line in out.splitlines() if (m := ROW.match(line))]


def test_a_row_per_form_and_controller_with_shares(capsys: pytest.CaptureFixture[str]) -> None:
    bench.main(["--runs", "40", "--forms", "1,6", "--controllers", "tasc-pwm,tasc-step"])
    out = capsys.readouterr().out
    rows = _rows(out)
    assert [(r["form"], r["ctrl"]) for r in rows] == [
        ("1", "tasc-pwm"), ("1", "tasc-step"), ("6", "tasc-pwm"), ("6", "tasc-step"),
    ]  # fmt: skip
    for r in rows:
        p30, ptol = float(r["p30"]), float(r["ptol"])
        assert 0.0 <= p30 <= ptol <= 100.0  # ±0.30 m lies inside the PSD tolerance (±0.35 m)
        # Misses off the patches, silent or braked, and on them: at most the runs outside ±0.30 m.
        on_patch = sum(int(k) for k in re.findall(r": (\d+)", r["rest"]))
        missed = round(40 * (100.0 - p30) / 100.0)
        assert int(r["silent"]) + int(r["eb"]) + on_patch == missed
    assert out.splitlines()[-2].startswith("below the target: ")


def test_the_detectors_only_variant_has_no_radar(capsys: pytest.CaptureFixture[str]) -> None:
    """Without the Doppler (SPEC §1 claim 6) and no initial brake step, the first command comes at
    the second detector and the train at Museum is braked short (tasc.md): the runs miss."""
    args = ["--runs", "10", "--forms", "6", "--controllers", "tasc-pwm", "--station", "Museum"]
    bench.main([*args, "--detectors-only"])
    out = capsys.readouterr().out
    assert out.startswith("Museum (detectors only), standard set, 10 runs per cell")
    (row,) = _rows(out)
    assert float(row["p30"]) < 50.0
    bench.main(args)
    (with_radar,) = _rows(capsys.readouterr().out)
    assert float(with_radar["p30"]) > float(row["p30"])


@pytest.mark.parametrize(
    "args", [["--forms", "9"], ["--controllers", "ato"], ["--runs", "0"], ["--station", "Nowhere"]]
)
def test_bad_arguments_are_refused_in_one_line(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        bench.main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    # argparse: its usage, then one error line naming the argument
    assert [line for line in err if "error:" in line] == [err[-1]], err
