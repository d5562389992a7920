"""Recording faults for the CLI fault table (``test_faults.CASES``): a bad recording
file fitted through :class:`hnn_pl.data.RecordingData`, each refused at construction in
one line naming the file and row (or the option that fixes it).

``CASES``: id → (argv, files, what the line must say); ``FILES``: files → the maker of
the case's working directory (a ``rec.yaml`` that points the data at ``rec.<suffix>``).
"""

from __future__ import annotations

import gzip
import pickle
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

HEADER = "trajectory,time,q1,p1\n"
#: four trajectories of three samples, ids 0 … 3: a valid recording to spoil
ROWS = [f"{m},{0.1 * j:.1f},{0.5 + m},{0.1 * j}" for m in range(4) for j in range(3)]

CONFIG = (
    "data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n"
    "    path: rec{suffix}\n    test_fraction: 0.5\n"
)

FIT = ["fit", "--config", "spring_fast.yaml", "--config", "rec.yaml", "--trainer.max_steps=2"]


def _csv(lines: list[str]) -> Callable[[Path], None]:
    """A maker of ``rec.csv`` holding the header and ``lines``."""

    def make(tmp: Path) -> None:
        (tmp / "rec.yaml").write_text(CONFIG.format(suffix=".csv"))
        (tmp / "rec.csv").write_text(HEADER + "\n".join(lines) + "\n")

    return make


def _spoiled(row: int, text: str) -> Callable[[Path], None]:
    """:data:`ROWS` with sample ``row`` (line ``row + 2``) replaced by ``text``."""
    return _csv([text if i == row else r for i, r in enumerate(ROWS)])


def _bytes(suffix: str, content: Callable[[], bytes]) -> Callable[[Path], None]:
    def make(tmp: Path) -> None:
        (tmp / "rec.yaml").write_text(CONFIG.format(suffix=suffix))
        (tmp / f"rec{suffix}").write_bytes(content())

    return make


def _gzip_csv() -> bytes:
    return gzip.compress((HEADER + "\n".join(ROWS) + "\n").encode(), mtime=0)


def _pickle() -> bytes:
    return pickle.dumps({"trajectory": [0, 0], "t": [0.0, 1.0], "y": [[0.0, 0.0]] * 2})


def _numpy_pt(tmp: Path) -> None:
    """A ``torch.save`` of numpy arrays, which ``weights_only`` loading refuses."""
    (tmp / "rec.yaml").write_text(CONFIG.format(suffix=".pt"))
    arrays = {"trajectory": np.zeros(2), "t": np.arange(2.0), "y": np.zeros((2, 2))}
    torch.save(arrays, tmp / "rec.pt")


def _uint64_npz(tmp: Path) -> None:
    (tmp / "rec.yaml").write_text(CONFIG.format(suffix=".npz"))
    ids = np.array([2**63, 2**63, 2**63 + 1, 2**63 + 1], dtype=np.uint64)
    np.savez(tmp / "rec.npz", trajectory=ids, t=np.array([0.0, 1, 0, 1]), y=np.zeros((4, 2)))


FILES: dict[str, Callable[[Path], None]] = {
    "recording-abc": _spoiled(4, "1,0.1,abc,0.1"),
    "recording-empty-cell": _spoiled(4, "1,0.1,,0.1"),
    "recording-underscore": _spoiled(4, "1,0.1,1_5,0.1"),
    "recording-hex": _spoiled(4, "1,0.1,0x10,0.1"),
    "recording-string-id": _spoiled(0, "a,0.0,0.5,0.0"),
    "recording-id-1e300": _spoiled(0, "1e300,0.0,0.5,0.0"),
    "recording-id-fraction": _spoiled(0, "1.5,0.0,0.5,0.0"),
    "recording-id-beyond-int64": _spoiled(0, "9223372036854775808,0.0,0.5,0.0"),
    "recording-gzip-csv": _bytes(".csv", _gzip_csv),
    "recording-pickle-npz": _bytes(".npz", _pickle),
    "recording-garbage-pt": _bytes(".pt", lambda: b"garbage" * 64),
    "recording-numpy-pt": _numpy_pt,
    "recording-uint64-ids": _uint64_npz,
    "recording-float32-spacing": _csv([*ROWS, "4,0.0,1,0", "4,1000.0,1,0", "4,1000.0001,1,0"]),
    "recording-float32-overflow": _spoiled(4, "1,0.1,1e39,0.1"),
    "recording-short-trajectory": _csv([*ROWS, "7,0.0,1,0", "7,0.1,1,0"]),
}

FLOAT64 = "set data.init_args.dtype: float64"

#: id: (argv, files, what the line must say)
CASES = {
    "recording-abc": (FIT, "recording-abc", "rec.csv, line 6, column 3 (q1): 'abc' is not"),
    "recording-empty-cell": (FIT, "recording-empty-cell", "rec.csv, line 6, column 3 (q1): empty"),
    "recording-underscore": (FIT, "recording-underscore", "line 6, column 3 (q1): '1_5' is not"),
    "recording-hex": (FIT, "recording-hex", "line 6, column 3 (q1): '0x10' is not a decimal"),
    "recording-string-id": (
        FIT,
        "recording-string-id",
        "rec.csv, line 2, column 1 (trajectory): 'a' is not an integer id",
    ),
    "recording-id-1e300": (
        FIT,
        "recording-id-1e300",
        "line 2: trajectory id 1e300 is beyond int64",
    ),
    "recording-id-fraction": (
        FIT,
        "recording-id-fraction",
        "rec.csv, line 2: trajectory id 1.5 is not an integer",
    ),
    "recording-id-beyond-int64": (
        FIT,
        "recording-id-beyond-int64",
        "line 2: trajectory id 9223372036854775808 is beyond int64",
    ),
    "recording-gzip-csv": (FIT, "recording-gzip-csv", "rec.csv: a gzip file, not a text file"),
    "recording-pickle-npz": (
        FIT,
        "recording-pickle-npz",
        "rec.npz: not an .npz archive of arrays (numpy.savez): a Python pickle, which is never",
    ),
    "recording-garbage-pt": (FIT, "recording-garbage-pt", "rec.pt: not a torch.save file of"),
    "recording-numpy-pt": (
        FIT,
        "recording-numpy-pt",
        "rec.pt: not a torch.save file of tensors (it holds Python objects other than tensors",
    ),
    "recording-uint64-ids": (
        FIT,
        "recording-uint64-ids",
        "rec.npz, row 0: trajectory id 9223372036854775808 is beyond int64",
    ),
    "recording-float32-spacing": (
        FIT,
        "recording-float32-spacing",
        "rec.csv, line 16: time 1000.0001 of trajectory 4 is 0.0001 after its previous sample, "
        "1000 after the trajectory's first; float32, the dtype times are served in, cannot "
        f"resolve that step there (makes it 0.000122): {FLOAT64}",
    ),
    "recording-float32-overflow": (
        FIT,
        "recording-float32-overflow",
        "rec.csv, line 6: q1 = 1e+39 is beyond float32 (largest 3.403e+38), the dtype it is "
        f"served in: {FLOAT64}",
    ),
    "recording-short-trajectory": (
        [*FIT, "--data.init_args.window=3"],
        "recording-short-trajectory",
        "recording rec.csv: trajectory 7 has 2 samples, fewer than window 3, so it would give no "
        "windows: set data.init_args.window: 2",
    ),
}
