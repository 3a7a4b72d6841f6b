"""``railstop telegram`` end to end, each run a process of its own (forked from a warm zygote)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from zygote import run_cli

EXE = [sys.executable, "-m", "railstop.cli", "telegram"]


def run(*args: str) -> subprocess.CompletedProcess[str]:
    """``railstop telegram ARGS``: a process of its own, forked from a warm zygote (tests/zygote.py)."""
    return run_cli("telegram", *args, timeout=120)


def one_line_error(p: subprocess.CompletedProcess[str]) -> str:
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, p.stderr
    assert lines[0].startswith("error: "), lines[0]
    return lines[0]


def test_encode_prints_lowercase_hex() -> None:
    # Reference frame of docs/telegrams.md (tests/link/test_link_codec.py checks it by hand).
    p = run("encode", "tasc-required-decel", "train_id=4660", "detector=2", "required_mps2=0.7")
    assert p.returncode == 0, p.stderr
    assert p.stdout == "9612340202bc85c1\n"


def test_decode_prints_every_field_with_units() -> None:
    p = run("decode", "21 00:07 00125174 411b 01 0036ef7a 000009c4 4eca")
    assert p.returncode == 0, p.stderr
    rows = {ln.split()[0]: ln.split(None, 1)[1] for ln in p.stdout.splitlines()}
    assert rows["type"].startswith("cbtc-report (0x21")
    assert rows["train_id"] == "7"
    assert rows["position_m"] == "1200.500 m"
    assert rows["speed_mps"] == "16.667 m/s"
    assert rows["direction"].startswith("L ")
    assert rows["time_s"] == "3600.250 s"


def test_round_trip_through_both_commands_json() -> None:
    fields = [
        "train_id=12",
        "detector=3",
        "speed_mps=-0.0125",
        "distance_m=35.25",
        "measured_s=61.0004",
        "passage_age_s=2.5",
    ]
    p = run("encode", "tasc-speed", *fields, "--json")
    assert p.returncode == 0, p.stderr
    encoded = json.loads(p.stdout)
    # Form 4 carries the speed and the distance (SPEC §1 para 92): a 15-byte payload, 18-byte frame.
    assert encoded["type"] == "tasc-speed" and encoded["bytes"] == 18
    p = run("decode", "--json", "0x" + encoded["hex"].upper())
    assert p.returncode == 0, p.stderr
    decoded = json.loads(p.stdout)
    # speed_mps -0.0125 is carried in mm/s: -12.5 rounds half to even to -12 mm/s.
    assert decoded == {
        "type": "tasc-speed",
        "code": 0x14,
        "fields": {
            "train_id": 12,
            "detector": 3,
            "speed_mps": -0.012,
            "distance_m": 35.25,
            "measured_s": 61.0,
            "passage_age_s": 2.5,
        },
    }


def test_types_lists_every_layout() -> None:
    p = run("types")
    assert p.returncode == 0, p.stderr
    for name in ("tasc-required-decel", "cbtc-command", "tc-occupancy", "door-command", "psd-status"):
        assert name in p.stdout
    assert "required_mps2" in p.stdout and "uint16" in p.stdout and "CRC-16" in p.stdout
    p = run("--help")
    assert p.returncode == 0 and "tasc-increase-decrease" in p.stdout


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("decode", "96 12 3z"), "bad hex"),
        (("decode", "9612340202bc85c2"), "rejected: crc:"),
        (("decode", "9612340202bc85"), "rejected: short:"),
        (("decode", "0012"), "rejected: unknown_type:"),
        (("encode", "tasc-brakes", "notch=1"), "unknown telegram type 'tasc-brakes'"),
        (("encode", "tasc-required-decel", "train_id=1", "detector=2"), "missing field 'required_mps2'"),
        (
            (
                "encode",
                "tasc-speed",
                "train_id=1",
                "detector=2",
                "speed_mps=3",
                "measured_s=10",
                "passage_age_s=1",
            ),
            "missing field 'distance_m'",
        ),
        (
            ("encode", "tasc-required-decel", "train_id=1", "detector=2", "required_mps2=1", "speed=2"),
            "unknown field 'speed'",
        ),
        (("encode", "tasc-required-decel", "train_id=1", "detector=2", "required_mps2=12.5"), "out_of_range"),
        (
            ("encode", "tasc-required-decel", "train_id=1", "detector=2", "required_mps2=nan"),
            "required_mps2=nan",
        ),
        (
            ("encode", "tasc-required-decel", "train_id=1", "detector", "required_mps2=1"),
            "expected FIELD=VALUE",
        ),
    ],
)
def test_errors_are_one_line_exit_2(args: tuple[str, ...], needle: str) -> None:
    line = one_line_error(run(*args))
    assert needle in line, line
