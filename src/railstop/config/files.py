"""Reading a file a user names: a regular file of bounded size, UTF-8, or one line of error.

Every data file (TOML, the operators file, railML) is read through :func:`read_file_bytes`, so that the
classes of bad input are closed once: a folder, a device (``/dev/zero``), a named pipe that
nobody writes (which would block for ever) or a socket is refused before it is opened; a file
larger than any data file is refused before it is read (a memory exhaustion otherwise); bytes
that are not UTF-8 are refused. Each as a :class:`~railstop.errors.ConfigError` naming the file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from railstop.errors import ConfigError

#: The largest data file read (the embedded line is 10 kB; a railML-sized line a few MB).
MAX_DATA_FILE_BYTES = 16 * 1024 * 1024


def read_text_file(path: str | Path, *, field: str = "(file)", limit: int = MAX_DATA_FILE_BYTES) -> str:
    """The UTF-8 text of the regular file ``path`` (at most ``limit`` bytes)."""
    raw = read_file_bytes(path, field=field, limit=limit)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(str(path), field, "not UTF-8 text") from None


def read_file_bytes(path: str | Path, *, field: str = "(file)", limit: int = MAX_DATA_FILE_BYTES) -> bytes:
    """The bytes of the regular file ``path`` (at most ``limit``): an XML file declares its own
    encoding."""
    name = str(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise ConfigError(name, field, "no such file") from None
    except OSError as exc:
        raise ConfigError(name, field, f"cannot read: {exc.strerror}") from None
    if stat.S_ISDIR(info.st_mode):
        raise ConfigError(name, field, "a folder, not a file")
    if not stat.S_ISREG(info.st_mode):
        raise ConfigError(name, field, "not a regular file (a device, a pipe or a socket)")
    if info.st_size > limit:
        raise ConfigError(name, field, f"too large for a data file ({info.st_size} bytes, at most {limit})")
    try:
        with open(path, "rb") as fh:
            raw = fh.read(limit + 1)
    except OSError as exc:
        raise ConfigError(name, field, f"cannot read: {exc.strerror}") from None
    if len(raw) > limit:  # it grew since
        raise ConfigError(name, field, f"too large for a data file (more than {limit} bytes)")
    return raw
