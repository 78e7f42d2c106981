"""Checks of command-line options and request values, each failure one clear line.

``argparse`` types (:func:`int_at_least`, :func:`float_at_least`) refuse an out-of-range
value while the command line is parsed (exit 2, the option named by argparse); a component
built from options (a matcher from ``mocapflow search --count/-k/--min-span``, a cleaner
from ``mocapflow clean --threshold``) turns its validation error into a :class:`ConfigError`
naming the option with :func:`options_error` (exit 2, also through the search server).
Only the standard library is imported here: the CLI's start-up stays lazy.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Mapping
from typing import Any

from .errors import ConfigError

#: Defaults of ``mocapflow sql``: seconds a query may run, and the memory DuckDB and the
#: result may take (DuckDB spills what it can to a private temporary folder within it).
SQL_TIMEOUT_S = 300.0
SQL_MEMORY_LIMIT = "4GB"


#: The largest value a numeric option takes (an integer fits a C int; a number of seconds is
#: 31 years): past it a count or a time is a typo, and the system calls it reaches overflow.
MAX_INT_OPTION = 2**31 - 1
MAX_FLOAT_OPTION = 1e9


def int_at_least(lo: int, most: int = MAX_INT_OPTION) -> Callable[[str], int]:
    """An argparse ``type``: an integer >= ``lo`` (and <= ``most``)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {text!r}") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {text!r}")
        if value > most:
            raise argparse.ArgumentTypeError(f"expected an integer <= {most}, got {text!r}")
        return value

    parse.__name__ = f"integer >= {lo}"
    return parse


def float_at_least(
    lo: float, *, above: bool = False, infinite: bool = False, most: float = MAX_FLOAT_OPTION
) -> Callable[[str], float]:
    """An argparse ``type``: a number >= ``lo`` (``above``: > ``lo``) and <= ``most``
    (``infinite``: ``inf`` allowed too)."""
    what = f"a number {'>' if above else '>='} {lo:g}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if math.isnan(value) or (math.isinf(value) and not infinite) or value < lo or (above and value == lo):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        if value > most and not math.isinf(value):
            raise argparse.ArgumentTypeError(f"expected {what} and <= {most:g}, got {text!r}")
        return value

    parse.__name__ = what
    return parse


def options_error(exc: Exception, options: Mapping[str, str], what: str) -> ConfigError:
    """A pydantic ``ValidationError`` of a component built from command-line options as a
    :class:`ConfigError` naming the option (``options``: parameter -> option, e.g.
    ``{"count": "--count"}``) and ``what`` was built (``matchers.search``)."""
    errors: list[dict[str, Any]] = getattr(exc, "errors", lambda: [])()
    if not errors:
        return ConfigError(f"{what}: {exc}")
    lines = []
    for err in errors:
        loc = ".".join(str(p) for p in err.get("loc", ()))
        key = str(err.get("loc", ("",))[0]) if err.get("loc") else ""
        name = options.get(key, f"parameter {loc!r}")
        lines.append(f"{name} {err.get('input')!r}: {err.get('msg', 'invalid value')} ({what})")
    return ConfigError("; ".join(lines))
