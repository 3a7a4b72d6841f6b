"""``railstop zones verify``: the CBTC zone controller's safety rules, checked exhaustively (SPEC §4)."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated

import typer

from railstop.cli.common import command_group, fail, out, print_verification
from railstop.cli.progress import Reporter

if TYPE_CHECKING:
    from railstop.verify.zones import VerifyResult

MODES = ("minimal", "conventional", "both")
# Beyond this many states the command stops with an error rather than run for hours.
MAX_STATES = 300_000

zones_app = command_group(
    "CBTC protection zones (SPEC §4): the zone controller's safety rules, proved on a small line."
)


@zones_app.command("verify")
def verify_cmd(
    mode: Annotated[
        str,
        typer.Option(help="Zone mode: minimal (segments), conventional (blocks and overlap) or both."),
    ] = "both",
    trains: Annotated[int, typer.Option(min=1, max=4, help="Trains on the line, all in direction R.")] = 3,
    segments: Annotated[
        int,
        typer.Option(min=2, max=8, help="Segments of 100 m (blocks of 2 segments); at least trains + 1."),
    ] = 6,
    max_losses: Annotated[
        int,
        typer.Option(
            "--max-losses",
            min=0,
            max=4,
            help="Reports lost in a row per train, at most (2 or more: trains get lost and re-detected).",
        ),
    ] = 3,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Explore every reachable state of the real zone controller and onboard units; exit 1 on a violation."""
    from railstop.verify.zones import ZoneModel, verify
    from railstop.wayside.zone_controller import ZoneMode

    if mode not in MODES:
        fail(f"--mode: must be one of {', '.join(MODES)} (got {mode!r})")
    if segments < trains + 1:
        fail(f"--segments: at least --trains + 1 = {trains + 1} segments (got {segments})")
    model = ZoneModel(trains=trains, segments=segments, max_losses=max_losses)
    modes = list(ZoneMode) if mode == "both" else [ZoneMode(mode)]
    results = []
    for m in modes:
        # The search runs a minute or two: its progress on stderr (states explored / found so far).
        with Reporter(f"zones verify ({m.value})", unit="states", enabled=not as_json) as rep:
            try:
                results.append(verify(model, mode=m, max_states=MAX_STATES, progress=rep.update))
            except RuntimeError as exc:
                fail(f"{exc}; choose fewer --trains, --segments or --max-losses")
    if as_json:
        print(json.dumps({"modes": [r.summary() for r in results]}))
    else:
        for r in results:
            _print_result(r)
    if any(r.violations for r in results):
        raise typer.Exit(1)


def _print_result(result: VerifyResult) -> None:

    from railstop.verify.zones import INVARIANTS

    m = result.model
    out.print(
        f"zones verify ({result.mode.value}): {m.trains} train(s) in direction R on {m.segments} segments "
        f"of {m.segment_m:g} m (blocks of {m.segments_per_block}), trains of {m.train_length_m:g} m, "
        f"a step of {m.step_m:g} m or none per {m.params.report_period_s:g} s cycle, up to {m.max_losses} "
        "reports lost in a row, moves while lost, manual releases; the real zone controller and onboard "
        "units",
        highlight=False,
        soft_wrap=True,
    )
    seen = ", ".join(f"{k} {n}" for k, n in result.coverage.items() if not k.startswith("status-"))
    print_verification(
        title=f"invariants ({result.mode.value} zones)",
        invariants=INVARIANTS,
        result=result,
        notes=[f"seen (transitions): {seen or 'nothing'}"],
    )
