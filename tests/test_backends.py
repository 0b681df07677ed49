"""The backend registry: names, no fallback, the CLI's choices."""

from __future__ import annotations

import pytest

from lde.cli import BACKEND_CHOICES
from lde.engine.backends import ALIASES, BACKENDS, DEFAULT_BACKEND, get_backend
from lde.errors import ConfigError


def test_cli_choices_are_the_registry():
    assert set(BACKEND_CHOICES) == set(BACKENDS)  # what --backend offers (help, error messages)
    assert all(a in BACKEND_CHOICES for a in ALIASES)  # still accepted, not offered
    assert set(ALIASES.values()) <= set(BACKENDS)


def test_names_the_spec_requires_and_the_default():
    """SPEC section 4: --backend fixed|float, default fixed; both are the lateral filter now, the
    paper's filter is paper-fixed / paper; 'lateral' (its earlier name) still works."""
    assert DEFAULT_BACKEND == "fixed"
    assert {"fixed", "float", "paper-fixed", "paper"} <= set(BACKENDS)
    assert get_backend("fixed").learns and get_backend("float").learns
    assert not get_backend("paper-fixed").learns and not get_backend("paper").learns
    assert get_backend("lateral") is get_backend("float")
    assert get_backend("paper-fixed").name == "paper-fixed"


def test_unknown_backend_is_a_config_error_never_a_fallback():
    with pytest.raises(ConfigError, match="unknown backend 'fixd'"):
        get_backend("fixd")
    assert get_backend("fixed").name == "fixed"
