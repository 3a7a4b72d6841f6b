"""The links' master key from a key file, never from a command line.

A key given on a command line is readable by every user of the machine (the
process list, ``/proc/PID/cmdline``) and stays in shell histories, so the live
processes, the office and the UDP tool read it from a file that only its owner
may read (or the environment). Every message names the option and the file,
never the key (a credential).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from railstop.errors import RailstopError
from railstop.link.safety import MIN_KEY_BYTES

KEY_FILE_MAX_BYTES = 4096  # a key file holds a key in hex: anything larger is not one


def key_from_hex(text: str, where: str) -> bytes:
    """A master key from its hex text (whitespace around it ignored), at least MIN_KEY_BYTES long;
    the messages name ``where``, never the text."""
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        raise RailstopError(f"{where}: not a key in hexadecimal") from None
    if not key:
        raise RailstopError(f"{where}: empty, no key in it")
    if len(key) < MIN_KEY_BYTES:
        raise RailstopError(
            f"{where}: at least {MIN_KEY_BYTES} bytes ({2 * MIN_KEY_BYTES} hex digits) are needed "
            f"(got {len(key)})"
        )
    return key


def read_key_file(path: Path, option: str = "--key-file") -> bytes:
    """The master key in a key file: hex (whitespace around it ignored), at least 16 bytes, in a
    regular file that group and others may neither read nor write (mode 0600 or stricter, as for
    the operators file). Anything else raises a RailstopError naming ``option``, the file and why;
    the process then never starts (DESIGN rule 10). [interpretation] The mode is checked on the
    open file (fstat), so a file swapped after the check is not read unchecked; a symbolic link is
    followed (secret stores mount keys so) and its target is what is checked."""
    where = f"{option}: {path}"
    try:
        # O_NONBLOCK: a FIFO given as the key file is not waited on (it is then refused below).
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise RailstopError(f"{where}: no such file") from None
    except OSError as exc:
        raise RailstopError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise RailstopError(f"{where}: not a regular file")
        if os.name == "posix" and info.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise RailstopError(
                f"{where}: group or others may read or write the key file (mode "
                f"{oct(stat.S_IMODE(info.st_mode))}): chmod 600 {path}"
            )
        data = b""
        while len(data) <= KEY_FILE_MAX_BYTES:
            chunk = os.read(fd, KEY_FILE_MAX_BYTES + 1 - len(data))
            if not chunk:
                break
            data += chunk
    except OSError as exc:
        raise RailstopError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if len(data) > KEY_FILE_MAX_BYTES:
        raise RailstopError(f"{where}: over {KEY_FILE_MAX_BYTES} bytes, not a key file")
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise RailstopError(f"{where}: not a key in hexadecimal") from None
    return key_from_hex(text, where)
