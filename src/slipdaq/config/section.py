"""What every config section shares: strict validation, and the one error a bad config raises."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class ConfigError(Exception):
    """A config that cannot be used; str() is one line naming the file, the key and what is expected."""


class _Section(BaseModel):
    """Strict: a TOML value must already have the key's type (no "1000" for 1000, no 1 for true); an integer is
    accepted for a float."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)
