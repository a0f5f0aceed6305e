from __future__ import annotations

import pytest
from hypothesis import settings

from slipdaq.config import Config, load_config
from support.paths import CONFIG

settings.register_profile("slipdaq", deadline=None)
settings.load_profile("slipdaq")
"""No per-example deadline: a property's examples take what the machine gives them (a busy CI host is slow, not
wrong); a test that needs a time bound states its own."""


@pytest.fixture
def cfg() -> Config:
    return load_config(CONFIG)
