"""Helpers that several test modules share: data generators and reference models the tests import by
name (``from helpers.frames import random_frames``).

They are a package, not fixtures, because the tests call them with arguments (a seed, a duration, a
vehicle) and child processes started by a test import them too; they are not in :mod:`lde.testing`
because a user testing their own code has no use for them. pytest puts ``tests/`` on ``sys.path``
(``pythonpath`` in ``pyproject.toml``); a child process adds :data:`TESTS` itself. No test module
imports another test module.
"""

from __future__ import annotations

from pathlib import Path

#: the directory that holds this package (put it on a child process's ``sys.path`` to import helpers)
TESTS = Path(__file__).resolve().parents[1]
