"""The train<->platform media of SPEC §5 as data (DESIGN rules 3 and 6): :class:`ChannelParams`
(one medium: bit rate, poll cycle, latency, loss, errors) and the presets of
``railstop/data/media.toml`` (:func:`load_media`). What the parameters mean, and the simulated
medium that uses them, are in ``railstop.link.channel``.
"""

from __future__ import annotations

import functools
import tomllib
from contextvars import ContextVar
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, RootModel, ValidationError, model_validator

from railstop.config.loader import read_toml, validate
from railstop.errors import ConfigError

DATA_PACKAGE = "railstop.data"
MEDIA_FILE = "media.toml"
#: The name that means the embedded media file in :func:`load_media`.
BUILTIN_MEDIA = "media"


# --------------------------------------------------------------------------
# Parameters (pydantic: validated, frozen, unknown keys rejected; DESIGN rules 3, 6)

# True while pydantic validates: ChannelParams.__init__ then lets ValidationError through.
_RAW: ContextVar[bool] = ContextVar("railstop_channel_params_raw", default=False)

Seconds = Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)]
Probability = Annotated[float, Field(strict=True, ge=0.0, le=1.0, allow_inf_nan=False)]


class ChannelParams(BaseModel):
    """One medium of SPEC §5. Times in seconds, probabilities per frame, BER per bit.

    Built directly, a bad value raises :class:`~railstop.errors.ConfigError`
    with source ``ChannelParams``; loaded from a file, the error names the file.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    # The medium's bit rate: a frame's airtime is (8 x its bytes + overhead_bits) / bit_rate_bps.
    bit_rate_bps: Annotated[float, Field(strict=True, gt=0.0, allow_inf_nan=False)]
    # SPEC §5 poll cycle; 0 = the frame leaves as soon as the medium is free.
    cycle_s: Seconds = 0.0
    latency_s: Seconds = 0.0  # propagation + processing
    jitter_s: Seconds = 0.0  # standard deviation of the latency (clipped at 0)
    loss_probability: Probability = 0.0  # independent, per frame
    burst_enter_probability: Probability = 0.0  # Gilbert–Elliott good -> bad, per frame
    burst_exit_probability: Probability = 0.0  # bad -> good, per frame
    burst_loss_probability: Probability = 0.0  # loss of a frame sent while bad
    # A delivered frame is sent again straight after the original with this probability, per frame.
    duplicate_probability: Probability = 0.0
    # A frame is held back by reorder_delay_s with this probability, per frame (frames sent after
    # it may then arrive first).
    reorder_probability: Probability = 0.0
    reorder_delay_s: Seconds = 0.0  # extra delay of a reordered (held back) frame
    bit_error_rate: Probability = 0.0  # per delivered bit, independent
    overhead_bits: Annotated[int, Field(strict=True, ge=0, le=1_000_000)] = 0  # preamble, sync, framing

    def __init__(self, **data: Any) -> None:
        # pydantic calls this __init__ for every instance it validates, nested ones
        # included; only the outermost call turns a ValidationError into the
        # project's one-line ConfigError (config.loader.validate), so a media file
        # still reports its own name and the full field path.
        if _RAW.get():
            super().__init__(**data)
            return
        token = _RAW.set(True)
        try:
            super().__init__(**data)
        except ValidationError:
            validate(ChannelParams, data, "ChannelParams")
            raise  # validate() raised already; kept for type checkers
        finally:
            _RAW.reset(token)

    def replace(self, **changes: Any) -> ChannelParams:
        """A validated copy with some fields changed (``model_copy`` would skip validation)."""
        return ChannelParams(**{**self.model_dump(), **changes})

    @property
    def burst_bad_fraction(self) -> float:
        """Stationary share of frames sent in the bad state: p_enter / (p_enter + p_exit)."""
        enter, leave = self.burst_enter_probability, self.burst_exit_probability
        if enter == 0.0:
            return 0.0  # the chain starts good and never leaves it
        return enter / (enter + leave)


# --------------------------------------------------------------------------
# Presets as data (DESIGN rule 3): railstop/data/media.toml


class MediaFile(RootModel[dict[str, ChannelParams]]):
    """A media file: one TOML table per medium, ``[name]`` with ChannelParams keys."""

    @model_validator(mode="after")
    def _not_empty(self) -> MediaFile:
        if not self.root:
            raise ValueError("a media file needs at least one [medium] table")
        return self


def _builtin() -> tuple[str, dict[str, Any]]:
    source = f"railstop/data/{MEDIA_FILE}"
    text = resources.files(DATA_PACKAGE).joinpath(MEDIA_FILE).read_text(encoding="utf-8")
    try:
        return source, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "(toml syntax)", str(exc)) from None


def load_media(name_or_path: str | Path | None = None) -> dict[str, ChannelParams]:
    """All media of a file: ``None`` or ``"media"`` = the embedded presets, else a TOML path.

    Unknown keys and bad values raise ConfigError naming the file, the field
    (``radio.latency_s``) and the value.
    """
    if name_or_path is None or (isinstance(name_or_path, str) and name_or_path == BUILTIN_MEDIA):
        return dict(_builtin_media())
    return _validated(str(name_or_path), read_toml(Path(name_or_path)))


@functools.cache
def _builtin_media() -> dict[str, ChannelParams]:
    """The embedded presets, read and validated once per process (every detailed stop asks)."""
    return _validated(*_builtin())


def _validated(source: str, data: dict[str, Any]) -> dict[str, ChannelParams]:
    token = _RAW.set(True)
    try:
        return dict(validate(MediaFile, data, source).root)
    finally:
        _RAW.reset(token)
