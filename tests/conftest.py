from __future__ import annotations

import pytest

from slipdaq.config import Config, load_config
from support.paths import CONFIG


@pytest.fixture
def cfg() -> Config:
    return load_config(CONFIG)
