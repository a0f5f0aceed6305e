"""What reading a log can raise."""

from __future__ import annotations

from slipdaq.sources.read_errors import InputError


class LogError(InputError):
    """A file that is not a readable slipdaq log."""
