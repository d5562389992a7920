"""argparse types that check a command-line number and name the option on a refusal
(``--seeds must be an integer >= 1, got '0'``), and a directory to write into. Light: no
torch, so ``--help`` stays quick."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from pathlib import Path

_INTEGER = re.compile(r"[+-]?[0-9]+")


def integer_at_least(least: int) -> Callable[[str], int]:
    """An argparse ``type``: a plain decimal integer ``>= least`` (``1_5``, ``0x10``,
    ``2.0`` refused), else ``--option must be an integer >= least, got '…'``."""

    def read(text: str) -> int:
        if not _INTEGER.fullmatch(text) or int(text) < least:
            raise argparse.ArgumentTypeError(f"must be an integer >= {least}, got {text!r}")
        return int(text)

    read.__name__ = f"integer_at_least_{least}"
    return read


#: counts: ``--starts``, ``--seeds``, ``--max-steps``
positive_int = integer_at_least(1)
#: ``--first-seed``; ``--workers`` (0: in this process)
non_negative_int = integer_at_least(0)

_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def finite_float(text: str) -> float:
    """An argparse ``type``: a plain decimal number that is finite as a float (``nan``,
    ``inf``, ``1e999``, ``1_5`` refused)."""
    value = float(text) if _DECIMAL.fullmatch(text) else math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """An argparse ``type``: a finite number ``> 0`` (a horizon, a step)."""
    value = float(text) if _DECIMAL.fullmatch(text) else math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def output_directory(text: str) -> Path:
    """An argparse ``type``: a directory to write into, absent (made when written) or a
    directory; a path naming a file, or below one, is refused."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a file; name a directory to write into")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{text}: {parent} is not a directory")
            break
    return path
