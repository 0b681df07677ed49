"""One exception root for lde; library errors are re-raised from it with ``from``.

Bad *frames* are never exceptions (they are counted rejections, see :mod:`lde.engine.receiver`);
these are for things a user must fix: a bad parameter file, an unreadable log, a bad option.
"""

from __future__ import annotations


class LdeError(Exception):
    """Root of every error lde raises on purpose."""


class ConfigError(LdeError, ValueError):
    """A parameter file, profile or option is invalid (the message says which field and why)."""


class LogFormatError(LdeError, ValueError):
    """A log file cannot be read: unknown format, corrupt, or not CAN frames."""


class OutputError(LdeError, OSError):
    """An output file cannot be written (disk full, file size limit, I/O error): what was written
    before stays in the file."""


class BusError(LdeError, OSError):
    """A CAN bus could not be opened or used."""
