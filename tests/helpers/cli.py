"""The ``lde`` command run in this process, as a user runs it, with its output captured."""

from __future__ import annotations

import contextlib
import io

from lde.cli import main


def run_lde(*argv: str) -> tuple[int, str, str]:
    """``lde ARGV`` in this process: (exit code, stdout, stderr). A traceback on stderr fails the test
    (bad input is a clear error, never a traceback)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    assert "Traceback" not in err.getvalue()
    return rc, out.getvalue(), err.getvalue()
