"""The loader's one-line messages (config/loader.py) for two slips of a hand-edited file: a
misspelt key, named with the key it should be, before the required key it leaves missing; and
a UTF-8 byte-order mark, which some editors write, accepted.

Real files in tmp_path, no mocks.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from railstop.config import load_line, load_vehicle
from railstop.config.loader import known_keys, validate
from railstop.config.operation import Operation, load_operation
from railstop.config.schema import Line, VehicleFile
from railstop.errors import ConfigError
from zygote import run_cli

DATA = Path(__file__).parents[2] / "src/railstop/data"
LINE_TEXT = (DATA / "line.toml").read_text(encoding="utf-8")
VEHICLE_TEXT = (DATA / "vehicle.toml").read_text(encoding="utf-8")


def _nth_replaced(text: str, old: str, new: str, n: int) -> str:
    """``text`` with the ``n``-th (0-based) occurrence of ``old`` replaced."""
    parts = text.split(old)
    assert len(parts) > n + 1, (old, n)
    return old.join(parts[: n + 1]) + new + old.join(parts[n + 1 :])


def _line_error(tmp_path: Path, text: str) -> ConfigError:
    path = tmp_path / "line.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_line(path)
    assert info.value.source == str(path)
    return info.value


def test_a_misspelt_required_key_is_named_with_the_key_it_should_be(tmp_path: Path) -> None:
    text = _nth_replaced(LINE_TEXT, "platform_length_m =", "platfrom_length_m =", 1)
    err = _line_error(tmp_path, text)
    assert err.field == "stations[1].platfrom_length_m", str(err)
    assert err.message == "unknown key (did you mean 'platform_length_m'?)"
    assert str(err) == (
        f"{tmp_path / 'line.toml'}: stations[1].platfrom_length_m: unknown key "
        "(did you mean 'platform_length_m'?)"
    )


@pytest.mark.parametrize(
    ("old", "new", "field", "meant"),
    [
        # A misspelt optional key, deep in a table and in a list of tables.
        (
            "beyond_stop_m = 10.0",
            "beyond_stopm = 10.0",
            "stations[0].tasc.doppler.beyond_stopm",
            "beyond_stop_m",
        ),
        ("permille = 0.0", "permile = 0.0", "stations[0].gradient[0].permile", "permille"),
        # A misspelt table.
        ("[line]", "[lines]", "lines", "line"),
    ],
)
def test_an_unknown_key_says_the_closest_known_one(
    tmp_path: Path, old: str, new: str, field: str, meant: str
) -> None:
    err = _line_error(tmp_path, _nth_replaced(LINE_TEXT, old, new, 0))
    assert err.field == field and err.message == f"unknown key (did you mean {meant!r}?)", str(err)


def test_an_unknown_key_like_no_known_one_gets_no_hint(tmp_path: Path) -> None:
    err = _line_error(
        tmp_path, _nth_replaced(LINE_TEXT, 'platform_side = "R"', 'platform_side = "R"\nzzz = 1', 1)
    )
    assert err.field == "stations[2].zzz" and err.message == "unknown key", str(err)


def test_a_missing_key_alone_is_still_reported_as_missing(tmp_path: Path) -> None:
    err = _line_error(tmp_path, _nth_replaced(LINE_TEXT, "platform_length_m = 130.0\n", "", 3))
    assert err.field == "stations[3].platform_length_m" and err.message == "Field required", str(err)


def test_the_vehicle_and_operation_files_say_it_too(tmp_path: Path) -> None:
    vehicle = tmp_path / "vehicle.toml"
    vehicle.write_text(VEHICLE_TEXT.replace("\ncars = 6", "\ncarz = 6"), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_vehicle(vehicle)
    assert str(info.value) == f"{vehicle}: vehicle.carz: unknown key (did you mean 'cars'?)"
    op = tmp_path / "op.toml"
    op.write_text('stations = [{ name = "Museum", dwel_s = 20.0 }]\n', encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_operation(op, load_line(None))
    assert str(info.value) == f"{op}: stations[0].dwel_s: unknown key (did you mean 'dwell_s'?)"


@pytest.mark.parametrize("text", ["", "# only a comment\n\n"])
def test_an_empty_operation_file_is_refused(tmp_path: Path, text: str) -> None:
    # Not silently the embedded 12 trains every 120 s.
    op = tmp_path / "op.toml"
    op.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_operation(op, load_line(None))
    assert str(info.value) == f"{op}: (file): the file is empty: give at least trains or headway_s"
    p = run_cli("check", "--operation", str(op), cwd=tmp_path)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert (p.stdout + p.stderr).strip().splitlines() == [
        f"error: {op}: (file): the file is empty: give at least trains or headway_s"
    ]


def test_known_keys_follow_the_location() -> None:
    assert "platform_length_m" in known_keys(Line, ("stations", 0))
    assert "beyond_stop_m" in known_keys(Line, ("stations", 3, "tasc", "doppler"))
    assert "cars" in known_keys(VehicleFile, ("vehicle",))
    assert known_keys(Operation, ("stations", 0)) == ["name", "dwell_s"]
    assert known_keys(Line, ("nowhere", 2)) == []


def test_validate_prefers_the_unknown_key_of_the_same_table_only() -> None:
    """A missing key in one table and an unknown key in another: the first problem, as before."""
    data = {"stations": [{"name": "A", "dwell_s": 10.0}, {"name": "B", "dwel_s": 10.0}], "trainz": 1}
    with pytest.raises(ConfigError) as info:
        validate(Operation, {"stations": [{"name": "A"}], "trainz": 1}, "op.toml")
    assert info.value.field == "stations[0].dwell_s" and info.value.message == "Field required"
    with pytest.raises(ConfigError) as info:
        validate(Operation, data, "op.toml")
    assert info.value.field == "stations[1].dwel_s"


def test_a_byte_order_mark_is_accepted(tmp_path: Path) -> None:
    path = tmp_path / "line.toml"
    path.write_bytes(b"\xef\xbb\xbf" + LINE_TEXT.encode("utf-8"))
    assert load_line(path) == load_line(None)


def test_the_command_says_it_in_one_line_exit_2(tmp_path: Path) -> None:
    (tmp_path / "line.toml").write_text(
        _nth_replaced(LINE_TEXT, "platform_length_m =", "platfrom_length_m =", 1), encoding="utf-8"
    )
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + LINE_TEXT.encode("utf-8"))
    p = run_cli("check", "--line", "line.toml", cwd=tmp_path)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines() == [
        "error: line.toml: stations[1].platfrom_length_m: unknown key (did you mean 'platform_length_m'?)"
    ]
    ok = run_cli("check", "--line", "bom.toml", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
