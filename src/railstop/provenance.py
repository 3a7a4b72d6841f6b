"""Where a result came from: the railstop version, when it was written, and a hash of its inputs.

Every report, plot and database row of railstop carries this, so that a figure
found in a slide deck months later can be traced to the code and the data that
made it (and made again: seed, run and disturbance set are named beside it).
"""

from __future__ import annotations

import hashlib
import json
from datetime import UTC, datetime
from typing import Any

from railstop import __version__


def inputs_sha256(*parts: Any) -> str:
    """The SHA-256 of JSON-serialisable inputs (pydantic models: pass ``model_dump(mode="json")``)."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def overrides_sha256(*models: Any) -> str | None:
    """The SHA-256 of data files given in place of embedded ones (pydantic models, None where the
    embedded file is used); None when every one is embedded, so that results on the embedded data
    keep their keys and identities."""
    if all(m is None for m in models):
        return None
    return inputs_sha256(*(None if m is None else m.model_dump(mode="json") for m in models))


def manifest_sha256(manifest: dict[str, Any]) -> str:
    """A campaign's identity: the SHA-256 of its manifest as sorted JSON (chunk files carry it)."""
    return hashlib.sha256(json.dumps(manifest, sort_keys=True).encode()).hexdigest()


def stamp(inputs: str | None = None) -> dict[str, Any]:
    """``{"railstop": version, "written_utc": ISO time, "inputs_sha256": inputs}``."""
    now = datetime.now(UTC).replace(microsecond=0)
    return {"railstop": __version__, "written_utc": now.isoformat(), "inputs_sha256": inputs}


def footer(prov: dict[str, Any], **named: object) -> str:
    """One line for a plot or page: ``railstop 0.1.0 · 2026-11-23 08:40 UTC · seed 1 · inputs 3f2a…``."""
    when = str(prov.get("written_utc", "")).replace("T", " ").replace("+00:00", " UTC")
    parts = [f"railstop {prov.get('railstop', '?')}", when]
    parts += [f"{k.replace('_', ' ')} {v}" for k, v in named.items() if v is not None]
    if prov.get("inputs_sha256"):
        parts.append(f"inputs {str(prov['inputs_sha256'])[:12]}")
    return " · ".join(p for p in parts if p)
