"""The backend registry: names, no fallback, the CLI's choices."""

from __future__ import annotations

import pytest

from lde.backends import BACKENDS, get_backend
from lde.cli import BACKEND_CHOICES
from lde.errors import ConfigError


def test_cli_choices_are_the_registry():
    assert set(BACKEND_CHOICES) == set(BACKENDS)


def test_unknown_backend_is_a_config_error_never_a_fallback():
    with pytest.raises(ConfigError, match="unknown backend 'fixd'"):
        get_backend("fixd")
    assert get_backend("fixed").name == "fixed"
