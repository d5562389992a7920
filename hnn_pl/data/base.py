"""What every task's DataModule shares: the on-disk cache, splits, fast loaders.

A task's data is a dict of float64 tensors made once by :meth:`generate` and cached
under ``cache_dir`` in a file named by a hash of the generation parameters, so a
second run with the same parameters skips generation. ``setup`` exposes:

- ``x_train, dx_train``: ``(N_train, D)`` inputs and target time derivatives;
- ``x_test, dx_test``: ``(N_test, D)``;
- ``test_t (T,)``, ``test_y (T, B, D)``: the clean held-out trajectories (times and
  states, time first as ``odeint`` returns them) that rollouts start from.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch import Tensor

CACHE_VERSION = 1


def default_cache_dir() -> Path:
    """``$HNN_PL_CACHE`` if set, else ``~/.cache/hnn_pl``."""
    return Path(os.environ.get("HNN_PL_CACHE", Path.home() / ".cache" / "hnn_pl"))


class TensorBatches:
    """Batches of rows of equal-length tensors, without a DataLoader's collate.

    With ``batch_size=None`` (or ≥ the number of rows) an epoch yields the tensors
    themselves ``repeats`` times: full-batch training costs nothing per step, and
    Lightning's per-epoch work (validation check, progress bar, callbacks) is paid
    once per ``repeats`` steps. Otherwise each epoch yields ``ceil(N / batch_size)``
    slices of one random permutation (``shuffle=True``, drawn from ``generator``)
    or of the identity.

    Args:
        tensors: tensors whose first axes have the same length ``N``.
        batch_size: rows per batch, or ``None`` for all rows.
        shuffle: draw a new permutation every epoch.
        generator: the random source of the permutations.
        repeats: full-batch steps per epoch (ignored for mini-batches).
    """

    def __init__(
        self,
        tensors: tuple[Tensor, ...],
        batch_size: int | None = None,
        shuffle: bool = False,
        generator: torch.Generator | None = None,
        repeats: int = 1,
    ) -> None:
        self.tensors = tensors
        self.n = len(tensors[0])
        self.batch_size = self.n if batch_size is None else min(batch_size, self.n)
        self.shuffle = shuffle
        self.generator = generator
        self.repeats = repeats if self.batch_size == self.n else 1

    def __len__(self) -> int:
        return self.repeats * -(-self.n // self.batch_size)

    def __iter__(self):
        if self.batch_size == self.n:
            for _ in range(self.repeats):
                yield self.tensors
            return
        index = torch.randperm(self.n, generator=self.generator) if self.shuffle else None
        for start in range(0, self.n, self.batch_size):
            if index is None:
                yield tuple(t[start : start + self.batch_size] for t in self.tensors)
            else:
                rows = index[start : start + self.batch_size]
                yield tuple(t[rows] for t in self.tensors)


class TrajectoryDataModule(L.LightningDataModule):
    """Base of the tasks' DataModules: cache, dtype, loaders, rollout targets.

    Subclasses implement :meth:`generate` (returning the float64 tensors listed in
    the module docstring), :meth:`cache_params` and the property ``state_dim``, and
    may set ``self.system`` (a :class:`~hnn_pl.systems.base.HamiltonianSystem`
    whose ``energy`` the rollout metrics use).

    Args:
        batch_size: training rows per step; ``None`` trains on the whole set.
        full_batch_steps: with ``batch_size=None``, training steps per epoch (so
            with the paper's 2000 full-batch steps and 100 here, fit runs 20
            epochs); mini-batch epochs are one pass over the training set.
        seed: seeds generation and the training order.
        cache_dir: where generated data is kept (default :func:`default_cache_dir`).
        dtype: ``"float32"`` or ``"float64"``, the dtype of the tensors served.
    """

    system = None

    def __init__(
        self,
        batch_size: int | None = None,
        full_batch_steps: int = 100,
        seed: int = 0,
        cache_dir: str | None = None,
        dtype: str = "float32",
    ) -> None:
        super().__init__()
        if dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
        self.batch_size = batch_size
        self.full_batch_steps = full_batch_steps
        self.seed = seed
        self.cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.dtype = getattr(torch, dtype)
        self.data: dict[str, Tensor] | None = None
        self._rollout_cache: dict[tuple, tuple[Tensor, Tensor]] = {}

    @property
    def state_dim(self) -> int:
        """``D``, the length of a state (``2k``)."""
        raise NotImplementedError

    def cache_params(self) -> dict[str, Any]:
        """Everything that determines :meth:`generate`'s output (JSON-serialisable)."""
        raise NotImplementedError

    def generate(self) -> dict[str, Tensor]:
        """Make the data set from scratch (float64 tensors)."""
        raise NotImplementedError

    @property
    def cache_path(self) -> Path:
        """``cache_dir/<ClassName>-<hash of cache_params>.pt``."""
        params = {"class": type(self).__name__, "version": CACHE_VERSION, **self.cache_params()}
        key = hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()
        return self.cache_dir / f"{type(self).__name__}-{key[:16]}.pt"

    def prepare_data(self) -> None:
        """Generate and cache the data set unless the cache already holds it."""
        path = self.cache_path
        if path.exists():
            return
        data = self.generate()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        torch.save(data, tmp)
        tmp.replace(path)

    def setup(self, stage: str | None = None) -> None:
        """Load the cached data (generating it if needed) in the served dtype."""
        if self.data is not None:
            return
        self.prepare_data()
        raw = torch.load(self.cache_path, weights_only=True)
        self.data = {k: v.to(self.dtype) if v.is_floating_point() else v for k, v in raw.items()}
        for key, value in self.data.items():
            setattr(self, key, value)

    def _generator(self, offset: int = 0) -> torch.Generator:
        return torch.Generator().manual_seed(self.seed + offset)

    def train_dataloader(self) -> TensorBatches:
        return TensorBatches(
            (self.x_train, self.dx_train),
            self.batch_size,
            shuffle=True,
            generator=self._generator(1),
            repeats=self.full_batch_steps,
        )

    def val_dataloader(self) -> TensorBatches:
        return TensorBatches((self.x_test, self.dx_test), self.batch_size)

    def test_dataloader(self) -> TensorBatches:
        return TensorBatches((self.x_test, self.dx_test), self.batch_size)

    def predict_dataloader(self) -> TensorBatches:
        return TensorBatches((self.x_test,), self.batch_size)

    def energy(self, y: Tensor) -> Tensor:
        """The physical energy of states ``(..., D) -> (...)`` that metrics compare."""
        if self.system is None:
            raise NotImplementedError(f"{type(self).__name__} defines no energy")
        return self.system.energy(y)

    def rollout_target(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """The true trajectories rollouts are compared with.

        Starts are the clean initial states of the held-out trajectories. With
        ``t_end=None`` the held-out trajectories themselves are returned; otherwise
        the system's ground truth on ``linspace(t₀, t_end, n_points)`` (computed in
        float64 once per horizon and kept).

        Returns:
            ``t (T,)`` and ``y (T, B, D)`` in the served dtype.
        """
        if t_end is None:
            return self.test_t, self.test_y
        key = (float(t_end), int(n_points or len(self.test_t)))
        if key not in self._rollout_cache:
            t = torch.linspace(float(self.test_t[0]), key[0], key[1], dtype=torch.float64)
            y = self.system.trajectory(self.test_y[0].to(torch.float64), t)
            self._rollout_cache[key] = (t.to(self.dtype), y.to(self.dtype))
        return self._rollout_cache[key]
