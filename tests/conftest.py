"""Shared pytest setup.

* Tests marked ``vcan`` need a real SocketCAN ``vcan0``. They run only where one exists (inside
  user-mode Linux: ``tests/test_uml.py`` drives them through ``tests/uml/run_in_uml.sh``);
  elsewhere they are skipped with the reason shown (``-ra`` is in the pytest options).
* ``virtual_channel``: a fresh python-can ``virtual`` bus channel name per test, so that tests
  never hear each other's frames.
"""

from __future__ import annotations

import itertools
import os
import socket
import sys

import pytest

VCAN = "vcan0"
#: tests/test_uml.py looks for this phrase to tell a missing vcan0 from a test's own skip
UML_HINT = "the vcan tests run inside user-mode Linux via tests/test_uml.py"
_channel_ids = itertools.count()


def real_vcan_reason(channel: str = VCAN) -> str | None:
    """None when a raw CAN socket binds to ``channel``; otherwise why not."""
    if not sys.platform.startswith("linux"):
        return f"needs Linux SocketCAN ({channel}); this is {sys.platform}"
    if not hasattr(socket, "AF_CAN"):
        return "this Python has no socket.AF_CAN"
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return f"no SocketCAN in this kernel ({exc.strerror}); {UML_HINT}"
    try:
        s.bind((channel,))
    except OSError as exc:
        return f"no usable {channel} ({exc.strerror}); {UML_HINT}"
    finally:
        s.close()
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    vcan_items = [it for it in items if it.get_closest_marker("vcan") is not None]
    if not vcan_items:
        return
    reason = real_vcan_reason()
    if reason is None:
        return
    skip = pytest.mark.skip(reason=reason)
    for it in vcan_items:
        it.add_marker(skip)


@pytest.fixture
def virtual_channel(request: pytest.FixtureRequest) -> str:
    """A python-can ``virtual`` channel name used by this test only."""
    return f"lde-test-{os.getpid()}-{next(_channel_ids)}-{request.node.name}"[:120]


@pytest.fixture
def vcan_channel() -> str:
    """The real SocketCAN channel of ``vcan``-marked tests."""
    return VCAN
