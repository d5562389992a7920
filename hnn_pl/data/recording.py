"""Recorded trajectories from a file: any number, any lengths and spacings.

A recording is a table of samples ``(trajectory, time, q₁ … q_k, p₁ … p_k)``, in one of
three files (the suffix picks the reader):

- ``.csv``: a header line ``trajectory,time,q1,…,qk,p1,…,pk`` (exactly these names),
  then one sample per line; lines starting with ``#`` and blank lines are skipped;
- ``.npz`` (``numpy.savez``) or ``.pt`` (``torch.save`` of a dict): arrays
  ``trajectory (S,)`` (integer ids), ``t (S,)`` and ``y (S, 2k)`` (``y = (q, p)``).

A trajectory is every sample with its id, in file order; its times must increase
strictly in that order and it needs at least two samples. Ids need not be contiguous
or sorted; trajectories are numbered ``0 … M − 1`` in increasing id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import torch
from torch import Tensor

from hnn_pl.data.base import TrajectoryDataModule, require, split_sizes
from hnn_pl.systems.base import HamiltonianSystem, system_spec

SUFFIXES = (".csv", ".npz", ".pt")


@dataclass
class Recording:
    """A validated recording, trajectory by trajectory: ``traj (S,)`` int64 ``0 … M − 1``
    (contiguous), ``t (S,)`` and ``y (S, D)`` float64 in increasing time within each,
    and ``ids (M,)`` the file's id of each trajectory."""

    path: str
    traj: Tensor
    t: Tensor
    y: Tensor
    ids: Tensor

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


def _read_csv(path: Path) -> tuple[np.ndarray, list[str]]:
    """The numbers ``(S, 2 + D)`` of a CSV recording and the name (``line n``) of each row."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        _fail(path, "", "not a text file")
    lines = [(n, line.strip()) for n, line in enumerate(text.splitlines(), 1)]
    lines = [(n, line) for n, line in lines if line and not line.startswith("#")]
    if not lines:
        _fail(path, "", "empty: expected a header trajectory,time,q1,…,qk,p1,…,pk")
    n_header, header = lines[0]
    names = [c.strip() for c in header.split(",")]
    k = (len(names) - 2) // 2
    expected = ["trajectory", "time", *(f"q{i}" for i in range(1, k + 1))]
    expected += [f"p{i}" for i in range(1, k + 1)]
    if k < 1 or names != expected:
        got = header if len(header) <= 60 else header[:57] + "..."
        _fail(
            path,
            f"line {n_header}",
            f"header must be trajectory,time,q1,…,qk,p1,…,pk (k ≥ 1), got {got!r}",
        )
    rows, where = [], []
    for n, line in lines[1:]:
        cells = line.split(",")
        if len(cells) != len(names):
            _fail(path, f"line {n}", f"{len(cells)} values, the header has {len(names)}")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            bad = next(c for c in cells if not _is_number(c))
            _fail(path, f"line {n}", f"{bad.strip()!r} is not a number")
        where.append(f"line {n}")
    if not rows:
        _fail(path, "", "no samples after the header")
    return np.asarray(rows, dtype=np.float64), where


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_arrays(path: Path) -> tuple[np.ndarray, list[str]]:
    """The numbers ``(S, 2 + D)`` of an ``.npz``/``.pt`` recording and ``row i`` names."""
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as f:
                arrays = {k: f[k] for k in f.files}
        else:
            arrays = torch.load(path, weights_only=True)
    except Exception as err:  # truncated, garbage, another format
        first = (str(err).strip().splitlines() or [""])[0][:100]
        _fail(path, "", f"cannot be read ({type(err).__name__}: {first})")
    if not isinstance(arrays, dict):
        _fail(path, "", f"expected a dict of trajectory, t, y; got a {type(arrays).__name__}")
    missing = [k for k in ("trajectory", "t", "y") if k not in arrays]
    if missing:
        _fail(path, "", f"missing {', '.join(missing)} (needs trajectory (S,), t (S,), y (S, 2k))")
    a = {}
    for key in ("trajectory", "t", "y"):
        value = arrays[key]
        value = value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
        if value.dtype.kind not in "iuf":
            _fail(path, "", f"{key} must be numbers, got dtype {value.dtype}")
        a[key] = value.astype(np.float64)
    s = len(a["t"]) if a["t"].ndim == 1 else -1
    d = a["y"].shape[1] if a["y"].ndim == 2 else 0
    if not (a["trajectory"].shape == a["t"].shape == (s,) and a["y"].shape == (s, d)):
        shapes = ", ".join(f"{k} {tuple(v.shape)}" for k, v in a.items())
        _fail(path, "", f"shapes must be trajectory (S,), t (S,), y (S, 2k); got {shapes}")
    if d < 2 or d % 2:
        _fail(path, "", f"y must have an even number 2k ≥ 2 of columns (q, p), got {d}")
    table = np.concatenate([a["trajectory"][:, None], a["t"][:, None], a["y"]], 1)
    return table, [f"row {i}" for i in range(s)]


def load_recording(path: str | Path) -> Recording:
    """Read and check a recording (module docstring for the formats).

    Raises:
        ValueError: one line naming the file and, where there is one, the row (``line
            n`` of a CSV, ``row i`` of the arrays): an unknown suffix, a missing or
            unreadable file, a bad header or shape, a non-number or non-finite value, a
            non-integer trajectory id, times not strictly increasing within a
            trajectory, a trajectory of fewer than two samples.
    """
    path = Path(path)
    if path.suffix not in SUFFIXES:
        _fail(path, "", f"unknown suffix {path.suffix!r}; use one of {', '.join(SUFFIXES)}")
    if not path.is_file():
        _fail(path, "", "no such file")
    table, where = _read_csv(path) if path.suffix == ".csv" else _read_arrays(path)
    bad = ~np.isfinite(table).all(1)
    if bad.any():
        i = int(np.argmax(bad))
        _fail(path, where[i], f"non-finite value in {_row_text(table[i])}")
    ids = table[:, 0]
    bad = ids != np.round(ids)
    if bad.any():
        i = int(np.argmax(bad))
        _fail(path, where[i], f"trajectory id {float(ids[i])!r} is not an integer")
    order = np.argsort(ids, kind="stable")
    same = ids[order][1:] == ids[order][:-1]
    back = same & (np.diff(table[order, 1]) <= 0)
    if back.any():
        j = int(np.argmax(back))
        i, prev = int(order[j + 1]), int(order[j])
        _fail(
            path,
            where[i],
            f"time {float(table[i, 1])!r} of trajectory {int(ids[i])} is not after its previous "
            f"sample's {float(table[prev, 1])!r} ({where[prev]})",
        )
    unique, first, counts = np.unique(ids, return_index=True, return_counts=True)
    if (counts < 2).any():
        j = int(np.argmax(counts < 2))
        _fail(
            path,
            where[int(first[j])],
            f"trajectory {int(unique[j])} has one sample; each needs at least two",
        )
    table = torch.from_numpy(table[order])
    traj = torch.from_numpy(np.repeat(np.arange(len(unique)), counts))
    return Recording(
        str(path), traj, table[:, 1].clone(), table[:, 2:].clone(), torch.tensor(unique).long()
    )


def _row_text(row: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:g}" for v in row) + ")"


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

    **Split.** Several trajectories: the ids ``test_trajectories`` are held out, else
    the last ``test_fraction`` of them (by id). One trajectory: a time segment is held
    out, the samples with ``test_segment[0] ≤ t ≤ test_segment[1]``, else the last
    ``test_fraction`` of its samples; the pieces before and after it (those of at least
    two samples) are the training trajectories.

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
        batch_size, full_batch_steps, seed, cache_dir, dtype, window, keep_fraction:
            see :class:`TrajectoryDataModule`.
    """

    def __init__(
        self,
        path: str,
        system: HamiltonianSystem | None = None,
        test_fraction: float = 0.2,
        test_trajectories: list[int] | None = None,
        test_segment: tuple[float, float] | None = None,
        differences: str = "central",
        batch_size: int | None = None,
        full_batch_steps: int = 100,
        seed: int | None = None,
        cache_dir: str | None = None,
        dtype: str = "float32",
        window: int | None = None,
        keep_fraction: float = 1.0,
    ) -> None:
        super().__init__(
            batch_size, full_batch_steps, seed, cache_dir, dtype, window, keep_fraction
        )
        require(
            differences in ("forward", "central"),
            f"differences must be 'forward' or 'central', got {differences!r}",
        )
        self.save_hyperparameters(ignore=["system", "cache_dir"])
        self.recording = self.read(path)
        self.path, self.differences = path, differences
        self.system = system
        self.hparams["system"] = None if system is None else system_spec(system)
        d = self.recording.y.shape[-1]
        require(
            system is None or system.state_dim == d,
            f"system {type(system).__name__} has state_dim {getattr(system, 'state_dim', d)}, "
            f"the recording {path} has {d} columns of (q, p)",
        )
        self.held_out = self._split(test_fraction, test_trajectories, test_segment)

    def read(self, path: str | None) -> Recording:
        """The recording at ``path``."""
        return load_recording(path)

    @property
    def state_dim(self) -> int:
        return self.recording.y.shape[-1]

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
            train = [b for m, b in enumerate(bounds) if m not in test]
            return train, [b for m, b in enumerate(bounds) if m in test]
        require(test_trajectories is None, f"{name}: one trajectory, use test_segment")
        n = len(rec.t)
        if test_segment is None:
            require(0 < test_fraction < 1, f"test_fraction must lie in (0, 1): {test_fraction}")
            lo, hi = n - round(test_fraction * n), n
        else:
            a, b = (float(v) for v in test_segment)
            lo, hi = (
                int(torch.searchsorted(rec.t, a)),
                int(torch.searchsorted(rec.t, b, right=True)),
            )
        return self.segment_split(lo, hi)

    def segment_split(
        self, lo: int, hi: int
    ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
        """A single recording's samples ``[lo, hi)`` held out, the pieces before and after
        it (of at least two samples) for training."""
        name, n = self.recording.path, len(self.recording.t)
        require(hi - lo >= 2, f"{name}: the held-out segment has {hi - lo} samples, needs 2")
        train = [(a, b) for a, b in ((0, lo), (hi, n)) if b - a >= 2]
        require(
            bool(train), f"{name}: no two consecutive samples left outside the held-out segment"
        )
        return train, [(lo, hi)]

    def cache_params(self) -> dict[str, Any]:
        return {"path": str(self.path)}

    def load_data(self) -> dict[str, Tensor]:
        """The tables, made from the recording read at construction (not cached)."""
        return self.generate()

    def generate(self) -> dict[str, Tensor]:
        rec = self.recording
        data: dict[str, Tensor] = {}
        for split, bounds in zip(("train", "test"), self.held_out, strict=True):
            pieces = [(rec.t[a:b], rec.y[a:b]) for a, b in bounds]
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
