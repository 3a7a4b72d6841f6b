"""The control room's operators and their credentials (issue 17 item 3: the manual zone release).

A TOML file, one table per operator, the credential stored only as a salted
PBKDF2-SHA256 hash (``railstop office add-operator FILE NAME`` writes it)::

    [operators.alice]
    pbkdf2_sha256 = "600000$<salt hex>$<hash hex>"

:func:`check` compares in constant time; an unknown operator costs the same
work as a known one (no timing tells which names exist).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import tomllib
from pathlib import Path

from railstop.errors import ConfigError

ITERATIONS = 600_000  # OWASP's figure for PBKDF2-HMAC-SHA256
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,40}$")
_DUMMY = f"{ITERATIONS}${'00' * 16}${'00' * 32}"


def hash_credential(secret: str, *, salt: bytes | None = None, iterations: int = ITERATIONS) -> str:
    salt = os.urandom(16) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha256", secret.encode(), salt, iterations)
    return f"{iterations}${salt.hex()}${digest.hex()}"


def _verify(secret: str, stored: str) -> bool:
    iterations, salt, digest = stored.split("$")
    got = hashlib.pbkdf2_hmac("sha256", secret.encode(), bytes.fromhex(salt), int(iterations))
    return hmac.compare_digest(got, bytes.fromhex(digest))


def load_operators(path: str | Path) -> dict[str, str]:
    """Operator name -> stored hash; a bad file raises a ConfigError naming file, field and value."""
    file = Path(path)
    try:
        data = tomllib.loads(file.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(str(file), "operators", exc.strerror or str(exc), str(file)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(file), "operators", f"not TOML: {exc}", None) from None
    table = data.get("operators")
    if not isinstance(table, dict) or not table:
        raise ConfigError(str(file), "operators", "needs an [operators.NAME] table per operator", None)
    out: dict[str, str] = {}
    for name, entry in table.items():
        if not _NAME.match(name):
            raise ConfigError(str(file), f"operators.{name}", "a name of letters, digits, _ . -", name)
        stored = entry.get("pbkdf2_sha256") if isinstance(entry, dict) else None
        parts = stored.split("$") if isinstance(stored, str) else []
        ok = len(parts) == 3 and parts[0].isdigit() and all(re.fullmatch(r"[0-9a-f]+", p) for p in parts[1:])
        if not ok:
            raise ConfigError(
                str(file), f"operators.{name}.pbkdf2_sha256", "expected ITERATIONS$SALT_HEX$HASH_HEX", stored
            )
        out[name] = str(stored)
    return out


def check(operators: dict[str, str], name: str, secret: str) -> bool:
    """Whether ``secret`` is ``name``'s credential."""
    stored = operators.get(name)
    result = _verify(secret, stored if stored is not None else _DUMMY)
    return stored is not None and result


def add_operator(path: str | Path, name: str, secret: str) -> None:
    """Add or replace ``name`` in the file (created if missing)."""
    if not _NAME.match(name):
        raise ConfigError(str(path), "name", "a name of letters, digits, _ . -", name)
    file = Path(path)
    existing = load_operators(file) if file.exists() else {}
    existing[name] = hash_credential(secret)
    lines = ["# railstop control-room operators: salted PBKDF2-SHA256 hashes, never the credentials.", ""]
    for n, stored in sorted(existing.items()):
        lines += [f"[operators.{n}]", f'pbkdf2_sha256 = "{stored}"', ""]
    file.write_text("\n".join(lines), encoding="utf-8")
