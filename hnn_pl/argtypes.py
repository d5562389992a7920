"""argparse types that check a command-line number and name the option on a refusal
(``--seeds must be an integer >= 1, got '0'``). Light: no torch, so ``--help`` stays quick."""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable

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
