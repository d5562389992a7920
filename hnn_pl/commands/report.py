"""What the report commands share: Markdown tables and the figures' files."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table: ``| h1 | h2 |``, the rule, one line per row (cells ``str``-ed)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(map(str, r)) + " |" for r in rows])


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> None:
    """Lay ``fig`` out, write it to ``path`` (its directory made) and close it."""
    from hnn_pl.plotting import pyplot

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
