"""The one exception hierarchy of mocapflow.

Every error mocapflow raises on purpose derives from :class:`MocapflowError`, so a
caller (and the CLI) can tell a user-facing problem from a bug with one ``except``.
"""

from __future__ import annotations

from pathlib import Path


class MocapflowError(Exception):
    """Base class of every error raised on purpose by mocapflow."""


class ParseError(MocapflowError):
    """A file could not be read.

    Parameters
    ----------
    path : str or Path
        The file that failed.
    line : int or None
        1-based line number where the problem was found (``None`` for binary formats
        or when the whole file is at fault).
    message : str
        What was found and what was expected instead.
    """

    def __init__(self, path: str | Path, line: int | None, message: str) -> None:
        self.path = str(path)
        self.line = line
        self.message = message
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")

    def __reduce__(
        self,
    ) -> tuple[type[ParseError], tuple[str, int | None, str]]:  # keep pickling (process pools) faithful to the fields
        return (type(self), (self.path, self.line, self.message))


class ConfigError(MocapflowError):
    """A pipeline, parameter or option is invalid; raised before anything runs."""


class PipelineError(MocapflowError):
    """A step failed while the pipeline was running."""


class PluginError(MocapflowError):
    """A plugin could not be loaded or registered a conflicting component."""


class DataError(MocapflowError):
    """Arrays or tables handed to a component do not have the expected shape or content."""


class LockError(MocapflowError):
    """A workspace is in use by another run (the message names it: pid, host, start time)."""
