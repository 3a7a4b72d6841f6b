"""railstop: precise station stopping and the train control around it."""

from __future__ import annotations

__version__ = "0.1.0"
