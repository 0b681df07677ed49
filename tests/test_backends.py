"""The backend registry: one module per backend, no fallback, removed names that name their
replacement, the CLI's help naming every backend."""

from __future__ import annotations

import pytest

from lde.cli import BACKEND_HELP, main
from lde.engine.backends import BACKENDS, DEFAULT_BACKEND, REMOVED, get_backend, make_backend_state
from lde.errors import ConfigError
from lde.params import load_vehicle


def test_names_the_spec_requires_and_the_default():
    """SPEC section 4: --backend fixed|float, default fixed (the lateral filter's firmware model and
    its float step); paper: the paper's filter in float, the seed's reference."""
    assert DEFAULT_BACKEND == "fixed"
    assert set(BACKENDS) == {"fixed", "float", "paper"}
    assert get_backend("fixed").learns and get_backend("float").learns
    assert not get_backend("paper").learns


def test_the_help_names_every_backend():
    for name in BACKENDS:
        assert f"{name}:" in BACKEND_HELP or f"{name} (default)" in BACKEND_HELP, name


def test_unknown_backend_is_a_config_error_never_a_fallback():
    with pytest.raises(ConfigError, match="unknown backend 'fixd'"):
        get_backend("fixd")
    assert get_backend("fixed").name == "fixed"


@pytest.mark.parametrize(("name", "instead"), [("lateral", "use float"), ("paper-fixed", "use fixed")])
def test_a_removed_name_is_one_error_naming_its_replacement(name, instead, capsys):
    assert name in REMOVED
    with pytest.raises(ConfigError, match=instead):
        get_backend(name)
    assert main(["replay", "no-such.log", "--backend", name, "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lde: error:") and instead in err[0], err


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_each_backend_declares_its_layout_by_name(name):
    """A backend's params and state are NamedTuples of named arrays (the layout declared once); a
    learning backend has the learner's arrays under the names the engine reads."""
    st = make_backend_state(name, load_vehicle("reference"))
    assert isinstance(st.state, get_backend(name).state_class)
    for part in (st.params, st.state):
        assert hasattr(part, "_fields") and part._fields
    if st.backend.learns:
        assert st.state.p.ndim == 1 and st.state.ls.ndim == 1 and st.params.lp.ndim == 1
