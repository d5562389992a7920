"""Recorded trajectories from a file: any number, any lengths and spacings.

A recording is a table of samples ``(trajectory, time, q₁ … q_k, p₁ … p_k)``, in one of
three files (the suffix picks the reader):

- ``.csv``: a header line ``trajectory,time,q1,…,qk,p1,…,pk`` (exactly these names;
  ``q,p`` for ``k = 1``), or ``trajectory,time,q1,…,qk`` (``q``) for positions alone,
  then one sample per line; lines starting with ``#`` and blank lines are skipped. Cells
  are read strictly: a trajectory id is an integer (``-12``; a float literal such as
  ``7.0`` only if it is exactly a whole number), every other cell a decimal number (``1.5``,
  ``-2e-3``; no ``_`` separators, no hex);
- ``.npz`` (``numpy.savez``) or ``.pt`` (``torch.save`` of a dict): arrays
  ``trajectory (S,)`` (integer ids; floats only if whole numbers within ``±2⁵³``),
  ``t (S,)`` and ``y (S, 2k)`` (``y = (q, p)``), or ``q (S, k)`` instead of ``y`` for
  positions alone. Nothing is unpickled: a pickle is refused.

A recording of positions alone (what a camera or an encoder records) is served with
``observe="positions"`` (:class:`RecordingData` sets it): the momenta are learned.

A trajectory is every sample with its id, in file order; its times must increase
strictly in that order and it needs at least two samples. Ids need not be contiguous
or sorted; trajectories are numbered ``0 … M − 1`` in increasing id.

**Times** are kept exact: each trajectory's times are shifted to start at 0 in float64
(integer times in int64) before any cast, and the shift ``t0`` (the file's time of its
first sample) is kept, so ``file time = t + t0[trajectory]``. **Served values** are
checked in the dtype they will be served in: a value that overflows it, or a time step
it changes by more than :data:`SPACING_RTOL`, is refused, naming ``dtype: float64``.
"""

from __future__ import annotations

import math
import pickle
import re
import warnings
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import torch
from torch import Tensor

from hnn_pl.data.base import TrajectoryDataModule, require, split_sizes, thinned_count
from hnn_pl.safe_io import torch_load
from hnn_pl.systems.base import HamiltonianSystem, system_spec

SUFFIXES = (".csv", ".npz", ".pt")

#: a time step that the served dtype changes by more than this share is refused
SPACING_RTOL = 0.01

#: the largest integer below which float64 holds every integer exactly (``2⁵³``)
EXACT_FLOAT_INT = 2**53

INT64 = (-(2**63), 2**63 - 1)

#: the option that serves a recording exactly
FLOAT64_FIX = "set data.init_args.dtype: float64"


@dataclass
class Recording:
    """A validated recording, trajectory by trajectory: ``traj (S,)`` int64 ``0 … M − 1``
    (contiguous), ``t (S,)`` float64 times since each trajectory's first sample (in
    increasing time within each), ``y (S, D)`` float64, ``ids (M,)`` int64 the file's id
    of each trajectory and ``t0 (M,)`` float64 the file's time of its first sample: a
    sample's time in the file is ``t + t0[traj]``."""

    path: str
    traj: Tensor
    t: Tensor
    y: Tensor
    ids: Tensor
    t0: Tensor
    positions: bool = False

    @property
    def state_dim(self) -> int:
        """``2k``: the state's width (a positions recording holds ``k`` columns)."""
        return self.y.shape[-1] * (2 if self.positions else 1)

    @property
    def n_trajectories(self) -> int:
        return len(self.ids)

    def bounds(self) -> list[tuple[int, int]]:
        """``[start, stop)`` rows of each trajectory."""
        counts = torch.bincount(self.traj, minlength=self.n_trajectories).tolist()
        stops = np.cumsum(counts).tolist()
        return [(stop - n, stop) for n, stop in zip(counts, stops, strict=True)]


def _fail(path: str | Path, where: str, problem: str) -> NoReturn:
    raise ValueError(f"recording {path}{', ' + where if where else ''}: {problem}")


def column_names(d: int, positions: bool = False) -> list[str]:
    """``trajectory, time, q1 … qk, p1 … pk`` for ``d = 2k`` state columns (``positions``:
    ``trajectory, time, q1 … qk`` for ``d = k``)."""
    k = d if positions else d // 2
    qs = [f"q{i}" for i in range(1, k + 1)]
    return ["trajectory", "time", *qs] + ([] if positions else [f"p{i}" for i in range(1, k + 1)])


#: the header forms, for messages
HEADERS = (
    "trajectory,time,q1,…,qk,p1,…,pk (or q,p), or trajectory,time,q1,…,qk (or q) for positions"
)


def header_names(names: list[str]) -> tuple[list[str], bool] | None:
    """``names`` in the canonical form of :func:`column_names` and whether they are
    positions alone, or ``None`` for a header of neither form (``q``/``p`` stand for
    ``q1``/``p1`` when ``k = 1``)."""
    short = {("q",): ["q1"], ("q", "p"): ["q1", "p1"]}
    canon = names[:2] + short.get(tuple(names[2:]), names[2:])
    d = len(canon) - 2
    for positions in (False, True):
        if d >= 1 and canon == column_names(d, positions) and (positions or d % 2 == 0):
            return canon, positions
    return None


# ------------------------------------------------------------------ file kinds

_MAGIC = (
    (b"\x1f\x8b", "a gzip file"),
    (b"BZh", "a bzip2 file"),
    (b"\xfd7zXZ\x00", "an xz file"),
    (b"\x28\xb5\x2f\xfd", "a zstd file"),
    (b"PK\x03\x04", "a zip archive"),
    (b"PK\x05\x06", "a zip archive"),
    (b"\x93NUMPY", "a .npy array"),
)


def _kind(path: Path) -> str | None:
    """What the first bytes of ``path`` say it is (``None``: no known signature);
    ``"a Python pickle"`` for a pickle stream of protocol 2 or later."""
    with path.open("rb") as f:
        head = f.read(8)
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    if len(head) >= 2 and head[0] == 0x80 and 2 <= head[1] <= 5:
        return "a Python pickle"
    return None


# --------------------------------------------------------------------- CSV

_INT = r"[+-]?[0-9]+"
_FLOAT = (
    r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
    r"|[iI][nN][fF](?:[iI][nN][iI][tT][yY])?|[nN][aA][nN])"
)
_INT_RE, _FLOAT_RE = re.compile(_INT), re.compile(_FLOAT)


def _lines(path: Path) -> Iterator[tuple[int, bytes]]:
    """``(n, line)`` of ``path`` from 1, split at ``\\n``, ``\\r\\n`` and ``\\r`` (as a
    text file opened with universal newlines), without the line ends."""
    n = 0
    with path.open("rb") as f:
        for raw in f:
            for piece in raw.splitlines():
                n += 1
                yield n, piece


def _text(path: Path, n: int, raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        _fail(path, f"line {n}", "not a text file (not UTF-8)")


def _header(path: Path, n: int, text: str) -> list[str]:
    """The canonical column names of the header line ``text`` (line ``n``), checked
    (:func:`header_names`)."""
    known = header_names([c.strip() for c in text.split(",")])
    if known is None:
        got = text if len(text) <= 60 else text[:57] + "..."
        _fail(path, f"line {n}", f"header must be {HEADERS}, got {got!r}")
    return known[0]


def _data_lines(path: Path) -> Iterator[tuple[int, str]]:
    """``(n, text)`` of the header (first) and then of every sample line of a CSV
    recording: stripped, blank lines and ``#`` comments skipped (and a UTF-8 byte order
    mark, as spreadsheets write)."""
    for n, raw in _lines(path):
        text = _text(path, n, raw).removeprefix("\ufeff" if n == 1 else "").strip()
        if text and not text.startswith("#"):
            yield n, text


def _int_id(path: Path, where: str, cell: str) -> int:
    """The trajectory id written in ``cell`` (stripped), exactly (a float-notation id
    such as ``7.0`` or ``1e3`` read as a decimal, never through float64), or a refusal."""
    if _INT_RE.fullmatch(cell):
        value = int(cell)
    elif _FLOAT_RE.fullmatch(cell):
        exact = Decimal(cell)
        if not (exact.is_finite() and exact == exact.to_integral_value()):
            _fail(path, where, f"trajectory id {cell} is not an integer")
        if abs(exact.adjusted()) > 40:  # far beyond int64: no huge integer made
            _fail(path, where, f"trajectory id {cell} is beyond int64 (|id| < 2⁶³)")
        value = int(exact)
    else:
        _fail(path, f"{where}, column 1 (trajectory)", f"{cell!r} is not an integer id")
    if not INT64[0] <= value <= INT64[1]:
        _fail(path, where, f"trajectory id {cell} is beyond int64 (|id| < 2⁶³)")
    return value


def _bad_cell(path: Path, where: str, names: list[str], cells: list[str]) -> NoReturn:
    """Refuse the first cell of a sample line that is not a number."""
    _int_id(path, where, cells[0].strip())
    for j, cell in enumerate(cells[1:], 2):
        text = cell.strip()
        if not _FLOAT_RE.fullmatch(text):
            problem = (
                "empty cell, expected a number" if not text else f"{text!r} is not a decimal number"
            )
            _fail(path, f"{where}, column {j} ({names[j - 1]})", problem)
    raise AssertionError("unreachable: every cell is a number")


def _read_csv_strict(path: Path) -> tuple[np.ndarray, np.ndarray, Callable[[int], str]]:
    """:func:`_read_csv` line by line: handles comments and blank lines anywhere and
    float-notation ids; the first bad line or cell is refused by name."""
    lines = _data_lines(path)
    first = next(lines, None)
    if first is None:
        _fail(path, "", f"empty: expected a header {HEADERS}")
    names = _header(path, *first)
    cell = r"\s*(" + _FLOAT + r")\s*"
    row = re.compile(",".join([cell] * len(names)))
    ids, values, where = array("q"), array("d"), array("q")
    for n, text in lines:
        match = row.fullmatch(text)
        if match is None:
            cells = text.split(",")
            if len(cells) != len(names):
                _fail(path, f"line {n}", f"{len(cells)} values, the header has {len(names)}")
            _bad_cell(path, f"line {n}", names, cells)
        cells = match.groups()
        ids.append(_int_id(path, f"line {n}", cells[0]))
        values.extend(map(float, cells[1:]))
        where.append(n)
    if not ids:
        _fail(path, "", "no samples after the header")
    table = np.frombuffer(values, dtype=np.float64).reshape(len(ids), len(names) - 1)
    lines_of = np.frombuffer(where, dtype=np.int64)
    return np.frombuffer(ids, dtype=np.int64), table, lambda i: f"line {int(lines_of[i])}"


def _read_csv_fast(path: Path) -> tuple[np.ndarray, np.ndarray, Callable[[int], str]] | None:
    """:func:`_read_csv` by ``numpy.loadtxt`` over the sample lines (its C parser is as
    strict as the line reader: no ``_``, no hex, ids as int64); ``None`` on any fault or
    a float-notation id, which the line reader then names or reads."""
    skipped: list[int] = []
    try:
        with path.open(encoding="utf-8-sig", newline=None) as f:
            n_header = 0
            while True:
                line = f.readline()
                n_header += 1
                text = line.strip()
                if not line or (text and not text.startswith("#")):
                    break
            if not text:
                return None
            names = _header(path, n_header, text)
            columns = np.dtype([("id", np.int64), ("v", np.float64, (len(names) - 1,))])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data"
                lines = _samples(f, n_header + 1, skipped)
                table = np.loadtxt(lines, columns, delimiter=",", comments=None, ndmin=1)
    except (ValueError, UnicodeDecodeError, OverflowError):
        return None
    if not len(table):
        return None
    return table["id"], table["v"], lambda i: f"line {_line_of(i, n_header, skipped)}"


def _samples(lines: Iterator[str], first: int, skipped: list[int]) -> Iterator[str]:
    """The sample lines of ``lines`` (numbered from ``first``): blank and ``#`` lines
    left out, their numbers appended to ``skipped``."""
    for n, line in enumerate(lines, first):
        text = line.lstrip()
        if not text or text[0] == "#":
            skipped.append(n)
        else:
            yield line


def _line_of(i: int, n_header: int, skipped: list[int]) -> int:
    """The line of sample ``i`` (from 0) after the header line ``n_header`` and the
    ``skipped`` lines (increasing)."""
    line = n_header + 1 + i
    for n in skipped:
        if n > line:
            break
        line += 1
    return line


def _read_csv(path: Path) -> tuple[np.ndarray, np.ndarray, Callable[[int], str]]:
    """``ids (S,)`` int64, ``values (S, 1 + D)`` float64 (time, q, p) and the name
    (``line n``) of each sample of a CSV recording."""
    kind = _kind(path)
    if kind is not None:
        hint = ": decompress it first" if kind.endswith("file") else ""
        _fail(path, "", f"{kind}, not a text file{hint}")
    return _read_csv_fast(path) or _read_csv_strict(path)


# ------------------------------------------------------------- npz and pt

KEYS = ("trajectory", "t", "y")
NEEDS = "needs trajectory (S,), t (S,), y (S, 2k) or q (S, k) for positions"


def _keys(available: Any) -> tuple[str, ...]:
    """The arrays to read: :data:`KEYS`, with ``q`` (positions) for ``y`` when a file
    has ``q`` and no ``y``."""
    return ("trajectory", "t", "q") if "q" in available and "y" not in available else KEYS


def _load_npz(path: Path) -> dict[str, Any]:
    kind = _kind(path)
    if kind != "a zip archive":
        what = f": {kind}" if kind else ""
        never = ", which is never loaded" if kind == "a Python pickle" else ""
        _fail(path, "", f"not an .npz archive of arrays (numpy.savez){what}{never}")
    arrays, problem = {}, None
    try:
        with np.load(path, allow_pickle=False) as f:
            keys = _keys(f.files)
            missing = [k for k in keys if k not in f.files]
            if missing:
                problem = f"missing {', '.join(missing)} ({NEEDS})"
            for key in keys if not missing else ():
                try:
                    arrays[key] = f[key]
                except ValueError as err:
                    if "allow_pickle" not in str(err):
                        raise
                    problem = f"{key} holds Python objects, which are never loaded; store numbers"
                    break
    except Exception:  # noqa: BLE001 - a damaged archive, whatever numpy or zipfile says
        problem = "a damaged .npz archive (cannot read its arrays)"
    if problem is not None:
        _fail(path, "", problem)
    return arrays


def _load_pt(path: Path) -> dict[str, Any]:
    kind = _kind(path)
    if kind not in ("a zip archive", "a Python pickle"):
        _fail(
            path,
            "",
            f"not a torch.save file of tensors ({kind or 'neither a zip archive nor a pickle'})",
        )
    problem = None
    try:
        loaded = torch_load(path)
    except pickle.UnpicklingError as err:
        problem = (
            "it holds Python objects other than tensors, numbers and dicts, which are never "
            "loaded; save torch tensors"
            if "global" in str(err).lower()
            else "damaged, or another format"
        )
    except Exception:  # noqa: BLE001 - truncated or damaged, whatever torch says
        problem = "damaged or truncated"
    if problem is not None:
        _fail(path, "", f"not a torch.save file of tensors ({problem})")
    if not isinstance(loaded, dict):
        _fail(path, "", f"expected a dict of trajectory, t, y; got a {type(loaded).__name__}")
    keys = _keys(loaded)
    missing = [k for k in keys if k not in loaded]
    if missing:
        _fail(path, "", f"missing {', '.join(missing)} ({NEEDS})")
    return {k: loaded[k] for k in keys}


def _numbers(path: Path, key: str, value: Any) -> np.ndarray:
    """``value`` as a numpy array of integers or floats, or a refusal naming ``key``."""
    if isinstance(value, Tensor):
        if value.is_complex() or value.dtype == torch.bool:
            _fail(path, "", f"{key} must be real numbers, got {value.dtype}")
        if value.is_floating_point() and value.dtype != torch.float64:
            value = value.to(torch.float64)  # float16/bfloat16 have no numpy twin
        return value.detach().cpu().numpy()
    try:
        a = np.asarray(value)
    except ValueError:
        _fail(path, "", f"{key} is not an array of numbers (ragged or mixed)")
    if a.dtype.kind in "US" and a.size:
        what = "trajectory id" if key == "trajectory" else key
        text = str(a.reshape(-1)[0])
        _fail(path, "row 0" if a.ndim else "", f"{what} {text!r} is text, not a number")
    if a.dtype.kind not in "iuf":
        _fail(path, "", f"{key} must be numbers, got dtype {a.dtype}")
    return a


def _array_ids(path: Path, ids: np.ndarray) -> np.ndarray:
    """Integer ids ``(S,)`` int64 from an integer array, or from a float array whose
    values are whole numbers within ``±2⁵³``; any other refused, naming the row."""
    if ids.dtype.kind == "u" and ids.size and ids.max() > INT64[1]:
        i = int(np.argmax(ids > INT64[1]))
        _fail(path, f"row {i}", f"trajectory id {int(ids[i])} is beyond int64 (|id| < 2⁶³)")
    if ids.dtype.kind in "iu":
        return ids.astype(np.int64)
    bad = ~np.isfinite(ids) | (ids != np.floor(ids))
    if bad.any():
        i = int(np.argmax(bad))
        _fail(path, f"row {i}", f"trajectory id {float(ids[i])!r} is not an integer")
    big = np.abs(ids) > EXACT_FLOAT_INT
    if big.any():
        i = int(np.argmax(big))
        _fail(
            path,
            f"row {i}",
            f"trajectory id {float(ids[i])!r} is a float beyond ±2⁵³, where floats stop "
            "being exact integers: store ids as integers",
        )
    return ids.astype(np.int64)


def _array_times(path: Path, t: np.ndarray) -> np.ndarray:
    """Times ``(S,)``: int64 for integer times (shifted exactly), else float64."""
    if t.dtype.kind == "u" and t.size and t.max() > INT64[1]:
        i = int(np.argmax(t > INT64[1]))
        _fail(path, f"row {i}", f"time {int(t[i])} is beyond int64")
    return t.astype(np.int64 if t.dtype.kind in "iu" else np.float64)


def _read_arrays(
    path: Path,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, Callable[[int], str], bool]:
    """``ids (S,)`` int64, ``t (S,)`` (int64 or float64), ``y (S, D)`` float64 of an
    ``.npz``/``.pt`` recording, the name (``row i``) of each sample, and whether ``y`` is
    positions alone (the file's ``q``)."""
    raw = _load_npz(path) if path.suffix == ".npz" else _load_pt(path)
    positions = "q" in raw
    a = {key: _numbers(path, key, raw[key]) for key in raw}
    y = a["q" if positions else "y"]
    s = len(a["t"]) if a["t"].ndim == 1 else -1
    d = y.shape[1] if y.ndim == 2 else 0
    want = "q (S, k)" if positions else "y (S, 2k)"
    if not (a["trajectory"].shape == a["t"].shape == (s,) and y.shape == (s, d)):
        shapes = ", ".join(f"{k} {tuple(v.shape)}" for k, v in a.items())
        _fail(path, "", f"shapes must be trajectory (S,), t (S,), {want}; got {shapes}")
    if d < 1 or (d % 2 and not positions):
        _fail(path, "", f"y must have an even number 2k ≥ 2 of columns (q, p), got {d}")
    if s == 0:
        _fail(path, "", "no samples")
    ids = _array_ids(path, a["trajectory"])
    t = _array_times(path, a["t"])
    return ids, t, y.astype(np.float64), lambda i: f"row {i}", positions


def _csv_positions(path: Path) -> bool:
    """Whether a (checked) CSV recording's header names positions alone."""
    n, text = next(_data_lines(path))
    return "p1" not in _header(path, n, text)


# ------------------------------------------------------------------ checks


def load_recording(
    path: str | Path, dtype: str | torch.dtype = torch.float64, shift: bool = True
) -> Recording:
    """Read and check a recording (module docstring for the formats and the rules).

    Args:
        path: a ``.csv``, ``.npz`` or ``.pt`` file.
        dtype: the dtype the values will be served in (``float32``: checked to fit
            it); the :class:`Recording` itself is float64.
        shift: shift each trajectory's times to start at 0 (``False``: keep the
            file's times, ``t0 = 0``).

    Raises:
        ValueError: one line naming the file and, where there is one, the row (``line
            n`` of a CSV, ``row i`` of the arrays): an unknown suffix, a missing or
            unreadable file, a bad header, shape or cell, a non-integer trajectory id,
            a non-finite value, times not strictly increasing within a trajectory, a
            trajectory of fewer than two samples, a value or time step the served
            ``dtype`` cannot hold.
    """
    path = Path(path)
    if path.suffix not in SUFFIXES:
        _fail(path, "", f"unknown suffix {path.suffix!r}; use one of {', '.join(SUFFIXES)}")
    if not path.is_file():
        _fail(path, "", "no such file")
    if path.suffix == ".csv":
        ids, values, where = _read_csv(path)
        t, y, positions = values[:, 0], values[:, 1:], _csv_positions(path)
    else:
        ids, t, y, where, positions = _read_arrays(path)
    return recording_from_arrays(path, ids, t, y, where, dtype, shift, positions)


def recording_from_arrays(
    path: str | Path,
    ids: np.ndarray,
    t: np.ndarray,
    y: np.ndarray,
    where: Callable[[int], str] = lambda i: f"row {i}",
    dtype: str | torch.dtype = torch.float64,
    shift: bool = True,
    positions: bool = False,
) -> Recording:
    """The checked :class:`Recording` of samples ``ids (S,)`` int64, ``t (S,)`` (float64,
    or int64: shifted exactly), ``y (S, D)`` float64 in file order (``positions``: ``q
    (S, k)``), ``where(i)`` naming sample ``i`` in messages (see :func:`load_recording`)."""
    names = column_names(y.shape[1], positions)
    _check_finite(path, ids, t, y, where)
    order = np.argsort(ids, kind="stable") if (ids[1:] < ids[:-1]).any() else None

    ids_s, t_s, y_s = (a if order is None else a[order] for a in (ids, t, y))

    def first(rows: np.ndarray) -> tuple[int, int]:
        """Of the sorted rows ``rows``, the first in file order: (sorted row, file row)."""
        in_file = rows if order is None else order[rows]
        k = int(np.argmin(in_file))
        return int(rows[k]), int(in_file[k])

    same = ids_s[1:] == ids_s[:-1]
    back = same & (t_s[1:] <= t_s[:-1])
    if back.any():
        s, i = first(np.flatnonzero(back) + 1)
        prev = s - 1 if order is None else int(order[s - 1])
        _fail(
            path,
            where(i),
            f"time {t[i].item()!r} of trajectory {ids[i].item()} is not after its previous "
            f"sample's {t[prev].item()!r} ({where(prev)})",
        )
    starts = np.flatnonzero(np.concatenate([[True], ~same]))
    counts = np.diff(np.append(starts, len(ids_s)))
    if (counts < 2).any():
        _, i = first(starts[counts < 2])
        _fail(path, where(i), f"trajectory {ids[i].item()} has one sample; each needs at least two")
    t0 = t_s[starts] if shift else np.zeros(len(starts), dtype=t_s.dtype)
    t_rel = (t_s - np.repeat(t0, counts)).astype(np.float64)
    if t_s.dtype.kind in "iu" and (t_rel < 0).any():
        _, i = first(np.flatnonzero(t_rel < 0))
        _fail(path, where(i), "the time since its trajectory's start is beyond int64")
    served = _served_dtype(dtype)
    if served != np.float64:
        _check_served(path, names, (ids_s, t_s, t_rel, y_s, same), first, where, served)
    traj = torch.from_numpy(np.repeat(np.arange(len(starts)), counts))
    return Recording(
        str(path),
        traj,
        torch.from_numpy(t_rel),
        torch.from_numpy(np.ascontiguousarray(y_s, dtype=np.float64)),
        torch.from_numpy(ids_s[starts].astype(np.int64)),
        torch.from_numpy(t0.astype(np.float64)),
        positions,
    )


def _check_finite(
    path: str | Path, ids: np.ndarray, t: np.ndarray, y: np.ndarray, where: Callable[[int], str]
) -> None:
    """Refuse the first sample (file order) with a non-finite time or value."""
    finite = np.isfinite(y).all(1)
    if t.dtype.kind == "f":
        finite &= np.isfinite(t)
    if not finite.all():
        i = int(np.argmin(finite))
        row = ", ".join([str(ids[i].item()), *(f"{v:g}" for v in [t[i].item(), *y[i].tolist()])])
        _fail(path, where(i), f"non-finite value in ({row})")


def _served_dtype(dtype: str | torch.dtype) -> np.dtype:
    name = str(dtype).removeprefix("torch.")
    if name not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    return np.dtype(name)


def _check_served(
    path: Path,
    names: list[str],
    arrays: tuple[np.ndarray, ...],
    first: Callable[[np.ndarray], tuple[int, int]],
    where: Callable[[int], str],
    served: np.dtype,
) -> None:
    """Refuse a value that overflows ``served`` and a time step ``t_{i+1} − t_i`` (since
    the shift) that ``served`` changes by more than :data:`SPACING_RTOL`. ``arrays``:
    the sorted ``ids (S,)``, file times ``(S,)``, shifted times ``(S,)`` float64, ``y (S,
    D)`` and ``same (S − 1,)`` (row ``i + 1`` in row ``i``'s trajectory)."""
    ids_s, t_s, t_rel, y_s, same = arrays
    with np.errstate(over="ignore"):
        over = np.isinf(y_s.astype(served))
        t_c = t_rel.astype(served)
    rows = over.any(1) | np.isinf(t_c)
    if rows.any():
        s, i = first(np.flatnonzero(rows))
        if np.isinf(t_c[s]):
            what = f"time since its trajectory's start {t_rel[s]:g}"
        else:
            c = int(np.argmax(over[s]))
            what = f"{names[2 + c]} = {y_s[s, c]:g}"
        _fail(
            path,
            where(i),
            f"{what} is beyond {served.name} (largest {np.finfo(served).max:.4g}), the dtype it "
            f"is served in: {FLOAT64_FIX}",
        )
    del over
    step = np.diff(t_rel)
    served_step = np.diff(t_c.astype(np.float64))
    off = same & (np.abs(served_step - step) > SPACING_RTOL * step)
    if off.any():
        s, i = first(np.flatnonzero(off) + 1)
        _fail(
            path,
            where(i),
            f"time {t_s[s].item()!r} of trajectory {ids_s[s].item()} is {step[s - 1]:.3g} after "
            f"its previous sample, {t_rel[s]:.6g} after the trajectory's first; {served.name}, "
            f"the dtype times are served in, cannot resolve that step there (makes it "
            f"{served_step[s - 1]:.3g}): {FLOAT64_FIX}",
        )


def differences(t: Tensor, y: Tensor, kind: str) -> tuple[Tensor, Tensor]:
    """Finite-difference pairs of one trajectory ``t (n,)``, ``y (n, D)``: ``forward``
    ``x_i = y_i``, ``(y_{i+1} − y_i)/(t_{i+1} − t_i)`` (``n − 1`` pairs); ``central``
    ``x_i = y_i``, ``(y_{i+1} − y_{i−1})/(t_{i+1} − t_{i−1})`` for ``0 < i < n − 1``."""
    if kind == "forward":
        return y[:-1], (y[1:] - y[:-1]) / (t[1:] - t[:-1])[:, None]
    return y[1:-1], (y[2:] - y[:-2]) / (t[2:] - t[:-2])[:, None]


def relative_grid(pieces: list[tuple[Tensor, Tensor]]) -> tuple[Tensor, Tensor]:
    """Trajectories ``(t_b (n_b,), y_b (n_b, D))`` on one time axis for rollouts from
    their first samples: one trajectory keeps its own times; several are placed on the
    union ``u (T,)`` of their times since start, ``y (T, B, D)`` NaN where a trajectory
    has no sample."""
    if len(pieces) == 1:
        t, y = pieces[0]
        return t, y[:, None]
    rel = [t - t[0] for t, _ in pieces]
    u = torch.unique(torch.cat(rel))
    out = torch.full((len(u), len(pieces), pieces[0][1].shape[-1]), math.nan, dtype=torch.float64)
    for b, (r, (_, y)) in enumerate(zip(rel, pieces, strict=True)):
        out[torch.searchsorted(u, r), b] = y
    return u, out


class RecordingData(TrajectoryDataModule):
    """Recorded trajectories (:func:`load_recording`): learn from states at times.

    **Times.** Each trajectory's times since its first sample (:func:`load_recording`):
    the served ``obs_t_*``, the windows and the rollouts' ``test_t`` are on that axis,
    so a recording with Unix-epoch times trains as one starting at 0; ``test_t0`` maps
    rollout times back to the file's. Values and time steps are checked at
    construction to fit ``dtype`` (else refused, naming ``dtype: float64``).

    **Split.** Several trajectories: the ids ``test_trajectories`` are held out, else
    the last ``test_fraction`` of them (by id). One trajectory: a time segment is held
    out, the samples with ``test_segment[0] ≤ t ≤ test_segment[1]`` (the file's times),
    else the last ``test_fraction`` of its samples; the pieces before and after it
    are the training trajectories, those that can give a training row: at least two
    samples, and with ``window`` at least ``window`` after thinning (a shorter piece is
    left out of the split).

    **Windows.** With ``window``, a trajectory of the file that would have fewer than
    ``window`` samples (after ``keep_fraction``'s thinning) gives no window: refused at
    construction, naming it and the longest ``window`` every trajectory allows; so is a
    held-out segment that short.

    **Served.** The observed states as the ``obs_*`` tables and, with ``window``, the
    loaders' windows (:class:`TrajectoryDataModule`). Without ``window``: finite
    differences within each trajectory as derivative pairs ``x``, ``dx``
    (``differences``, see :func:`differences`).

    **Rollouts.** From each held-out trajectory's first sample, compared with its
    samples (``rollout_target``, ``t_end=None`` only: there is no truth beyond the
    recording). One held-out trajectory keeps its own times; several share the union
    of their times since their starts, ``NaN`` where one has no sample (the metrics
    skip those). ``system`` (optional) gives the energy the metrics compare;
    without it energy metrics are skipped.

    Args:
        path: the recording (``.csv``, ``.npz`` or ``.pt``).
        system: a :class:`~hnn_pl.systems.base.HamiltonianSystem` whose ``energy``
            scores rollouts, or ``None``.
        test_fraction: share of trajectories (or of one trajectory's samples) held out.
        test_trajectories: the file's ids of the held-out trajectories.
        test_segment: ``(t_a, t_b)``: the held-out times of a single recording.
        differences: ``"central"`` or ``"forward"`` derivative pairs.
        **kwargs: the data options of :class:`TrajectoryDataModule` (``batch_size``,
            ``seed``, ``dtype``, ``window``, ``observe``, …).
    """

    def __init__(
        self,
        path: str,
        system: HamiltonianSystem | None = None,
        test_fraction: float = 0.2,
        test_trajectories: list[int] | None = None,
        test_segment: tuple[float, float] | None = None,
        differences: str = "central",
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        require(
            differences in ("forward", "central"),
            f"differences must be 'forward' or 'central', got {differences!r}",
        )
        self.recording = self.read(path)
        if self.recording.positions:
            self.observe = self.hparams["observe"] = "positions"
        self.path, self.differences = path, differences
        self.system = system
        self.hparams["system"] = None if system is None else system_spec(system)
        d = self.recording.state_dim
        require(
            system is None or system.state_dim == d,
            f"system {type(system).__name__} has state_dim {getattr(system, 'state_dim', d)}, "
            f"the recording {path} has {d} columns of (q, p)",
        )
        self.held_out = self._split(test_fraction, test_trajectories, test_segment)

    def read(self, path: str | None) -> Recording:
        """The recording at ``path``, checked to fit the served dtype."""
        return load_recording(path, self.dtype)

    @property
    def test_t0(self) -> Tensor:
        """``(B,)`` float64: for each held-out trajectory (a column of ``test_y``), the
        file's time of ``test_t``'s 0, so its samples' file times are ``test_t + t0[b]``
        (one held-out trajectory keeps its times since its first sample; several start
        at 0 each, :func:`relative_grid`)."""
        rec, test = self.recording, self.held_out[1]
        starts = torch.tensor([a for a, _ in test])
        t0 = rec.t0[rec.traj[starts]]
        return t0 + rec.t[starts] if len(test) > 1 else t0

    def _refuse_short(self, bounds: list[tuple[int, int]]) -> None:
        """With ``window``: refuse the first trajectory of ``bounds`` that would keep
        fewer than ``window`` samples after thinning (it would give no window)."""
        if self.window is None:
            return
        kept = [thinned_count(b - a, self.keep_fraction) for a, b in bounds]
        short = [m for m, k in enumerate(kept) if k < self.window]
        if not short:
            return
        rec, (a, b) = self.recording, bounds[short[0]]
        raise ValueError(
            f"recording {rec.path}: trajectory {int(rec.ids[rec.traj[a]])} "
            f"{self._samples(b - a)}, fewer than window {self.window}, so it would give no "
            f"windows: set data.init_args.window: {min(kept)}"
        )

    def _samples(self, n: int) -> str:
        """``has n samples``, or with thinning ``keeps k of its n samples (…)``."""
        k = thinned_count(n, self.keep_fraction)
        if k == n:
            return f"has {n} samples"
        return f"keeps {k} of its {n} samples (keep_fraction {self.keep_fraction})"

    @property
    def state_dim(self) -> int:
        return self.recording.state_dim

    @property
    def has_energy(self) -> bool:
        """A system is set and the recording holds momenta (a positions recording's
        truth has none, so no energy is scored)."""
        return self.system is not None and not self.recording.positions

    def _split(
        self,
        test_fraction: float,
        test_trajectories: list[int] | None,
        test_segment: tuple[float, float] | None,
    ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
        """``(train, test)`` row ranges ``[start, stop)`` of the recording."""
        rec, name = self.recording, self.recording.path
        bounds = rec.bounds()
        if rec.n_trajectories > 1:
            require(test_segment is None, f"{name}: test_segment is for a single recording")
            if test_trajectories is None:
                n_test = split_sizes(rec.n_trajectories, test_fraction)
                test = set(range(rec.n_trajectories - n_test, rec.n_trajectories))
            else:
                ids = rec.ids.tolist()
                unknown = [i for i in test_trajectories if i not in ids]
                require(not unknown, f"{name}: no trajectory with id {unknown} to hold out")
                test = {ids.index(i) for i in test_trajectories}
                require(
                    0 < len(test) < rec.n_trajectories,
                    f"{name}: test_trajectories must leave at least one trajectory in each split",
                )
            self._refuse_short(bounds)
            train = [b for m, b in enumerate(bounds) if m not in test]
            return train, [b for m, b in enumerate(bounds) if m in test]
        require(test_trajectories is None, f"{name}: one trajectory, use test_segment")
        n = len(rec.t)
        if test_segment is None:
            require(0 < test_fraction < 1, f"test_fraction must lie in (0, 1): {test_fraction}")
            lo, hi = n - round(test_fraction * n), n
        else:
            a, b = (float(v) - float(rec.t0[0]) for v in test_segment)
            lo, hi = (
                int(torch.searchsorted(rec.t, a)),
                int(torch.searchsorted(rec.t, b, right=True)),
            )
        return self.segment_split(lo, hi)

    def segment_split(
        self, lo: int, hi: int
    ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
        """A single recording's samples ``[lo, hi)`` held out, the pieces before and after
        it that can give a training row for training (class docstring)."""
        name, n = self.recording.path, len(self.recording.t)
        require(hi - lo >= 2, f"{name}: the held-out segment has {hi - lo} samples, needs 2")
        kept = thinned_count(hi - lo, self.keep_fraction)
        require(
            self.window is None or kept >= self.window,
            f"{name}: the held-out segment {self._samples(hi - lo)}, fewer than window "
            f"{self.window}, so it would give no windows: set data.init_args.window: {kept}",
        )
        need = max(2, self.window or 2)
        train = [
            (a, b)
            for a, b in ((0, lo), (hi, n))
            if b - a >= 2 and thinned_count(b - a, self.keep_fraction) >= need
        ]
        require(
            bool(train),
            f"{name}: no two consecutive samples left outside the held-out segment"
            if self.window is None
            else f"{name}: no piece outside the held-out segment keeps window {self.window} "
            "samples",
        )
        return train, [(lo, hi)]

    def cache_params(self) -> dict[str, Any]:
        return {"path": str(self.path)}

    def load_data(self) -> dict[str, Tensor]:
        """The tables, made from the recording read at construction (not cached)."""
        return self.generate()

    def generate(self) -> dict[str, Tensor]:
        rec = self.recording
        y_all = rec.y
        if rec.positions:  # the truth's momenta are unknown: NaN, never scored
            y_all = torch.cat([rec.y, torch.full_like(rec.y, math.nan)], -1)
        data: dict[str, Tensor] = {}
        for split, bounds in zip(("train", "test"), self.held_out, strict=True):
            pieces = [(rec.t[a:b], y_all[a:b]) for a, b in bounds]
            data[f"obs_y_{split}"] = torch.cat([y for _, y in pieces])
            data[f"obs_t_{split}"] = torch.cat([t for t, _ in pieces])
            data[f"obs_traj_{split}"] = torch.cat(
                [torch.full((len(t),), m, dtype=torch.int64) for m, (t, _) in enumerate(pieces)]
            )
            pairs = [differences(t, y, self.differences) for t, y in pieces]
            data[f"x_{split}"] = torch.cat([x for x, _ in pairs])
            data[f"dx_{split}"] = torch.cat([dx for _, dx in pairs])
            if split == "test":
                data["test_t"], data["test_y"] = relative_grid(pieces)
        require(
            self.window is not None or (len(data["x_train"]) and len(data["x_test"])),
            f"{rec.path}: no {self.differences} differences in a split (trajectories too short); "
            "set window or differences: forward",
        )
        return data

    def true_field(self, t: Tensor, y: Tensor) -> None:
        """``None``: a recording has no true ``dy/dt`` (an energy's field is a fit, not the
        truth), so no field error is scored; :class:`RealPendulumData` differences its
        one measured segment."""
        return None

    def rollout_target(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """The held-out samples ``t (T,)``, ``y (T, B, D)`` (see the class docstring); a
        ``t_end`` other than ``None`` raises ``ValueError`` (no truth off the recording)."""
        if t_end is not None:
            raise ValueError("a recording has no ground truth off its samples: t_end: null")
        return self.test_t, self.test_y
