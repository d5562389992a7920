"""What the report commands share: Markdown tables, the figures' files, a PNG writer.

``python -m hnn_pl.experiments.report [path]`` (re)draws ``docs/pixel_frames.png``.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor


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


def save_png(path: str | Path, image_uint8: Tensor | Sequence) -> None:
    """Write ``image_uint8``, ``(H, W)`` grayscale or ``(H, W, 3)`` RGB with values 0..255
    (anything ``torch.as_tensor`` takes), as an 8-bit PNG to ``path`` (parents created),
    with nothing but ``zlib``."""
    img = torch.as_tensor(image_uint8)
    if img.dtype != torch.uint8:
        if img.is_floating_point() or img.min() < 0 or img.max() > 255:
            raise ValueError("save_png expects integer values in 0..255 (uint8)")
        img = img.to(torch.uint8)
    if img.dim() == 2:
        color_type, channels = 0, 1
    elif img.dim() == 3 and img.shape[-1] == 3:
        color_type, channels = 2, 3
    else:
        raise ValueError(f"expected (H, W) or (H, W, 3), got {tuple(img.shape)}")
    height, width = img.shape[:2]
    rows = img.cpu().contiguous().reshape(height, width * channels)
    raw = torch.cat([torch.zeros(height, 1, dtype=torch.uint8), rows], dim=1)  # filter 0
    data = raw.numpy().tobytes()

    def chunk(tag: bytes, payload: bytes) -> bytes:
        body = tag + payload
        return struct.pack(">I", len(payload)) + body + struct.pack(">I", zlib.crc32(body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, color_type, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
    png += chunk(b"IDAT", zlib.compress(data, 9)) + chunk(b"IEND", b"")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)


def pixel_frames(argv: Sequence[str] | None = None) -> None:
    """Nine rendered frames at θ = −0.6 … 0.6 in one PNG (``docs/pixel_frames.png``)."""
    import sys

    from hnn_pl.render import frame_strip, render_pendulum

    argv = sys.argv[1:] if argv is None else argv
    path = argv[0] if argv else "docs/pixel_frames.png"
    theta = torch.linspace(-0.6, 0.6, 9, dtype=torch.float64)
    save_png(path, frame_strip(render_pendulum(theta), scale=4, gap=1))
    print(f"wrote {path}: 9 frames at θ = −0.6, −0.45, …, 0.6")


if __name__ == "__main__":
    pixel_frames()
