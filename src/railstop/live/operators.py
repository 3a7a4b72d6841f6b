"""The control room's operators and their credentials (the page's login and its commands).

A TOML file, one table per operator: the operator's id (1..65535, carried by
every command telegram the operator sends, SPEC §4 step 5 and §5) and the
credential stored only as a salted PBKDF2-SHA256 hash (``railstop office
add-operator FILE NAME`` writes it)::

    [operators.alice]
    id = 3
    pbkdf2_sha256 = "600000$<salt hex>$<hash hex>"

The file is written with mode 0600 and refused when group or others may read
or write it (the hashes are what an offline guesser needs). :func:`check`
compares in constant time; an unknown operator costs the same work as a known
one (no timing tells which names exist).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import stat
import tomllib
from dataclasses import dataclass
from pathlib import Path

from railstop.config.files import read_text_file
from railstop.errors import ConfigError

ITERATIONS = 600_000  # OWASP's figure for PBKDF2-HMAC-SHA256
MIN_CREDENTIAL_CHARS = 8
MAX_OPERATOR_ID = 0xFFFF  # the command telegrams' operator field is 16 bits (link.codec)
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,40}$")
_DUMMY = f"{ITERATIONS}${'00' * 16}${'00' * 32}"


@dataclass(frozen=True, slots=True, kw_only=True)
class Operator:
    """One operator: the id the command telegrams carry and the stored hash."""

    id: int
    pbkdf2_sha256: str


def hash_credential(secret: str, *, salt: bytes | None = None, iterations: int = ITERATIONS) -> str:
    salt = os.urandom(16) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha256", secret.encode(), salt, iterations)
    return f"{iterations}${salt.hex()}${digest.hex()}"


def _verify(secret: str, stored: str) -> bool:
    iterations, salt, digest = stored.split("$")
    got = hashlib.pbkdf2_hmac("sha256", secret.encode(), bytes.fromhex(salt), int(iterations))
    return hmac.compare_digest(got, bytes.fromhex(digest))


def check_mode(file: Path) -> None:
    """Refuse a file that group or others may read or write (POSIX only): a ConfigError."""
    if os.name != "posix":
        return
    try:
        mode = file.stat().st_mode
    except OSError as exc:
        raise ConfigError(str(file), "operators", exc.strerror or str(exc), str(file)) from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(
            str(file),
            "mode",
            f"group or others may read or write the operators file: chmod 600 {file}",
            oct(stat.S_IMODE(mode)),
        )


def load_operators(path: str | Path) -> dict[str, Operator]:
    """Operator name -> Operator; a bad (or too open) file raises a ConfigError naming file, field
    and value."""
    file = Path(path)
    text = read_text_file(file, field="operators")
    check_mode(file)
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise ConfigError(str(file), "operators", f"not TOML: {exc or 'nested too deeply'}", None) from None
    table = data.get("operators")
    if not isinstance(table, dict) or not table:
        raise ConfigError(str(file), "operators", "needs an [operators.NAME] table per operator", None)
    out: dict[str, Operator] = {}
    ids: dict[int, str] = {}
    for name, entry in table.items():
        if not _NAME.match(name):
            raise ConfigError(str(file), f"operators.{name}", "a name of letters, digits, _ . -", name)
        entry = entry if isinstance(entry, dict) else {}
        stored = entry.get("pbkdf2_sha256")
        parts = stored.split("$") if isinstance(stored, str) else []
        ok = len(parts) == 3 and parts[0].isdigit() and all(re.fullmatch(r"[0-9a-f]+", p) for p in parts[1:])
        if not ok:
            raise ConfigError(
                str(file), f"operators.{name}.pbkdf2_sha256", "expected ITERATIONS$SALT_HEX$HASH_HEX", stored
            )
        # SPEC §4 step 5 / §5: every command names its operator; an operator without an id (or with
        # another's) could only be recorded wrongly, so the file is refused.
        op_id = entry.get("id")
        if not isinstance(op_id, int) or isinstance(op_id, bool) or not 1 <= op_id <= MAX_OPERATOR_ID:
            raise ConfigError(str(file), f"operators.{name}.id", f"an integer 1..{MAX_OPERATOR_ID}", op_id)
        if op_id in ids:
            raise ConfigError(str(file), f"operators.{name}.id", f"already {ids[op_id]}'s id", op_id)
        ids[op_id] = name
        out[name] = Operator(id=op_id, pbkdf2_sha256=str(stored))
    return out


def check(operators: dict[str, Operator], name: str, secret: str) -> bool:
    """Whether ``secret`` is ``name``'s credential (the same work for an unknown name)."""
    op = operators.get(name)
    result = _verify(secret, op.pbkdf2_sha256 if op is not None else _DUMMY)
    return op is not None and result


def add_operator(
    path: str | Path, name: str, secret: str, *, op_id: int | None = None, iterations: int = ITERATIONS
) -> int:
    """Add or replace ``name`` in the file (created if missing, always written with mode 0600);
    ``op_id`` None: the operator's id so far, or the next free one. Returns the id."""
    file = Path(path)
    if not _NAME.match(name):
        raise ConfigError(str(file), "name", "a name of letters, digits, _ . -", name)
    if len(secret) < MIN_CREDENTIAL_CHARS:
        raise ConfigError(str(file), "credential", f"at least {MIN_CREDENTIAL_CHARS} characters", None)
    if len(set(secret.strip())) < 2:  # blanks only, or one character repeated: no credential at all
        raise ConfigError(str(file), "credential", "more than one distinct character, not only blanks", None)
    existing = load_operators(file) if file.exists() else {}
    if op_id is None:
        op_id = (
            existing[name].id if name in existing else max((o.id for o in existing.values()), default=0) + 1
        )
    if not 1 <= op_id <= MAX_OPERATOR_ID:
        raise ConfigError(str(file), "id", f"an integer 1..{MAX_OPERATOR_ID}", op_id)
    other = next((n for n, o in existing.items() if o.id == op_id and n != name), None)
    if other is not None:
        raise ConfigError(str(file), "id", f"already {other}'s id", op_id)
    existing[name] = Operator(id=op_id, pbkdf2_sha256=hash_credential(secret, iterations=iterations))
    lines = ["# railstop control-room operators: salted PBKDF2-SHA256 hashes, never the credentials.", ""]
    for n, op in sorted(existing.items()):
        lines += [f"[operators.{n}]", f"id = {op.id}", f'pbkdf2_sha256 = "{op.pbkdf2_sha256}"', ""]
    # Written to a new 0600 file beside it, then renamed over it: never readable by others, not even
    # for a moment, and never half written.
    tmp = file.with_name(f".{file.name}.{os.getpid()}.tmp")
    try:
        tmp.unlink(missing_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write("\n".join(lines))
        os.replace(tmp, file)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ConfigError(str(file), "operators", exc.strerror or str(exc), str(file)) from None
    return op_id
