"""``railstop telegram``: encode, decode and list the train↔wayside telegrams (railstop.link.codec)."""

from __future__ import annotations

import json
import re
from typing import Annotated

import typer

from railstop.cli.common import command_group, fail, out
from railstop.errors import TelegramError

#: The telegram types' names for the group's help, in the codec's order (``railstop.link.codec``
#: ``TYPES``, equal by a test): the help is built without importing the codec and numpy.
TYPE_NAMES = (
    "tasc-position",
    "tasc-distance",
    "tasc-interval",
    "tasc-speed",
    "tasc-decel",
    "tasc-required-decel",
    "tasc-brake-command",
    "tasc-increase-decrease",
    "tasc-emergency-stop",
    "cbtc-report",
    "cbtc-command",
    "zone-release",
    "tc-occupancy",
    "door-command",
    "wcc-command",
    "psd-status",
)

telegram_app = command_group(
    "Encode, decode and list the telegrams (type | payload | CRC-16, big-endian). Types: "
    + ", ".join(TYPE_NAMES)
    + "."
)

_SEPARATORS = re.compile(r"[\s:_-]+")


def _parse_hex(text: str) -> bytes:
    """Hex digits, optionally with a 0x prefix and spaces, colons, dashes or underscores between bytes."""
    s = _SEPARATORS.sub("", text.strip())
    if s[:2].lower() == "0x":
        s = s[2:]
    try:
        return bytes.fromhex(s)
    except ValueError:
        fail(f"bad hex: {text!r} (hex digits in pairs, optionally separated by spaces or colons)")


@telegram_app.command("decode")
def decode_cmd(
    hex_text: Annotated[str, typer.Argument(metavar="HEX", help="The frame in hex (spaces/colons allowed).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Decode a telegram frame and print every field with its unit."""
    from railstop.link.codec import decode, describe, layout_of

    data = _parse_hex(hex_text)
    try:
        msg = decode(data)
    except TelegramError as exc:
        fail(f"rejected: {exc}")
    layout = layout_of(msg)
    if as_json:
        values = {a: getattr(msg, a) for f in layout.fields for a in f.attributes}
        print(json.dumps({"type": layout.name, "code": layout.code, "fields": values}))
        return
    rows = [("type", f"{layout.name} (0x{layout.code:02x}: {layout.description})"), *describe(msg)]
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        out.print(f"{name:<{width}}  {value}", highlight=False, soft_wrap=True)


@telegram_app.command("encode")
def encode_cmd(
    type_name: Annotated[str, typer.Argument(metavar="TYPE", help="Telegram type (see `types`).")],
    assignments: Annotated[
        list[str] | None, typer.Argument(metavar="FIELD=VALUE...", help="Every field of the type.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Encode a telegram from FIELD=VALUE pairs and print the frame in lowercase hex."""
    from railstop.link.codec import TYPES, encode, from_fields

    if type_name not in TYPES:
        fail(f"unknown telegram type {type_name!r}; choose one of: {', '.join(TYPES)}")
    values: dict[str, str] = {}
    for item in assignments or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            fail(f"{item!r}: expected FIELD=VALUE")
        if name in values:
            fail(f"{name}: given twice")
        values[name] = value
    try:
        frame = encode(from_fields(type_name, values))
    except TelegramError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps({"type": type_name, "hex": frame.hex(), "bytes": len(frame)}))
        return
    print(frame.hex())


@telegram_app.command("types")
def types_cmd(
    markdown: Annotated[
        bool, typer.Option("--markdown", help="Print the layout tables of docs/telegrams.md instead.")
    ] = False,
) -> None:
    """List every telegram type with its byte layout."""
    from railstop.link.codec import LAYOUTS, layout_markdown

    if markdown:
        print(layout_markdown(), end="")
        return
    for layout in LAYOUTS.values():
        out.print(
            f"{layout.name}  type 0x{layout.code:02x}, {layout.frame_size} bytes "
            f"({layout.payload_size}-byte payload), {layout.medium}: {layout.description}",
            highlight=False,
            soft_wrap=True,
        )
        out.print(f"  {0:>2}  {'type':<18} {'uint8':<6}  0x{layout.code:02x}", highlight=False)
        offset = 1
        for f in layout.fields:
            lo, hi = f.bounds()
            unit = f" {f.unit} (resolution {f.resolution})" if f.kind == "fixed" else ""
            out.print(
                f"  {offset:>2}  {f.name:<18} {f.wire_type:<6}  {lo}..{hi}{unit}: {f.description}",
                highlight=False,
                soft_wrap=True,
            )
            offset += f.size
        out.print(f"  {offset:>2}  {'crc':<18} {'uint16':<6}  CRC-16/CCITT-FALSE", highlight=False)
