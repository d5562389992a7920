"""What every task's DataModule shares: the on-disk cache, splits, fast loaders.

A task's data is a dict of float64 tensors made once by :meth:`generate` and cached
under ``cache_dir`` in a file named by a hash of the generation parameters, so a
second run with the same parameters skips generation. ``setup`` exposes:

- ``x_train, dx_train``: ``(N_train, D)`` inputs and target time derivatives;
- ``x_test, dx_test``: ``(N_test, D)``;
- ``test_t (T,)``, ``test_y (T, B, D)``: the clean held-out trajectories (times and
  states, time first as ``odeint`` returns them) that rollouts start from.

State tasks also serve their draws as observed trajectories (no derivatives), a flat
table per split (``train``, ``test``), samples of one trajectory contiguous and in
increasing time:

- ``obs_y_<split> (S, D)``: the observed (noisy) states;
- ``obs_t_<split> (S,)``: their times;
- ``obs_traj_<split> (S,)`` int64: trajectory id ``0 … M − 1``
  (``n_<split>_trajectories = M``);
- with ``window=K``: ``windows_<split> (W, K)`` int64 rows of that table, one per
  start whose ``K`` consecutive samples lie in one trajectory (``None`` without).
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch import Tensor

from hnn_pl.safe_io import no_space, save_atomic

CACHE_VERSION = 2


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

    **Data parallel** (``world_size`` W > 1): ``batch_size`` is the *global* batch.
    Every rank draws the same permutation (seed ``generator`` alike) and takes the
    contiguous block ``[⌊r·m/W⌋, ⌊(r+1)·m/W⌋)`` of each global batch of ``m`` rows
    (full batch: a view, the same every step): disjoint, in rank order the global
    batch, sizes within one. With ``W | m`` DDP's averaged gradient equals the
    one-process one exactly (else row weights are off by ``≤ 1/⌊m/W⌋``). A last
    global batch of fewer than ``W`` rows joins the one before, so every rank
    yields the same number of non-empty batches.

    Args:
        tensors: tensors whose first axes have the same length ``N``.
        batch_size: rows per (global) batch, or ``None`` for all rows.
        shuffle, generator: a new permutation from ``generator`` every epoch.
        repeats: full-batch steps per epoch (ignored for mini-batches).
        rank, world_size: this process's data-parallel rank and the number ``W``.
    """

    def __init__(
        self,
        tensors: tuple[Tensor, ...],
        batch_size: int | None = None,
        shuffle: bool = False,
        generator: torch.Generator | None = None,
        repeats: int = 1,
        rank: int = 0,
        world_size: int = 1,
    ) -> None:
        self.tensors = tensors
        self.n = len(tensors[0])
        self.batch_size = self.n if batch_size is None else min(batch_size, self.n)
        self.shuffle = shuffle
        self.generator = generator
        self.repeats = repeats if self.batch_size == self.n else 1
        if not 0 <= rank < world_size:
            raise ValueError(
                f"need 0 <= rank < world_size, got rank={rank}, world_size={world_size}"
            )
        if world_size > 1 and self.batch_size < world_size:
            raise ValueError(
                f"{world_size} data-parallel processes need at least as many rows per batch; "
                f"got batch_size={batch_size} of {self.n} rows"
            )
        self.rank = rank
        self.world_size = world_size

    def _global_batches(self) -> list[tuple[int, int]]:
        """``(start, stop)`` of each global batch; a tail of < ``W`` rows is merged."""
        bounds = [(s, min(s + self.batch_size, self.n)) for s in range(0, self.n, self.batch_size)]
        if len(bounds) > 1 and bounds[-1][1] - bounds[-1][0] < self.world_size:
            bounds[-2:] = [(bounds[-2][0], self.n)]
        return bounds

    def _shard(self, start: int, stop: int) -> tuple[int, int]:
        """This rank's block ``(lo, hi)`` of the global batch ``[start, stop)``."""
        m, w, r = stop - start, self.world_size, self.rank
        return start + r * m // w, start + (r + 1) * m // w

    def __len__(self) -> int:
        return self.repeats * len(self._global_batches())

    def __iter__(self):
        if self.batch_size == self.n:
            lo, hi = self._shard(0, self.n)
            batch = self.tensors if hi - lo == self.n else tuple(t[lo:hi] for t in self.tensors)
            for _ in range(self.repeats):
                yield batch
            return
        index = torch.randperm(self.n, generator=self.generator) if self.shuffle else None
        for start, stop in self._global_batches():
            lo, hi = self._shard(start, stop)
            if index is None:
                yield tuple(t[lo:hi] for t in self.tensors)
            else:
                rows = index[lo:hi]
                yield tuple(t[rows] for t in self.tensors)


def data_parallel_rank(trainer: L.Trainer | None = None) -> tuple[int, int]:
    """``(rank, world_size)`` of this process among those that split the data: the
    trainer's ``distributed_sampler_kwargs`` (what Lightning's ``DistributedSampler``
    would use; ``(0, 1)`` for single-device strategies), else an initialised
    ``torch.distributed`` group, else ``(0, 1)``. Lightning never shards a
    non-DataLoader iterable such as :class:`TensorBatches`, so the loaders do."""
    if trainer is not None:
        kwargs = trainer.distributed_sampler_kwargs
        return (int(kwargs["rank"]), int(kwargs["num_replicas"])) if kwargs else (0, 1)
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return 0, 1


class TrajectoryDataModule(L.LightningDataModule):
    """Base of the tasks' DataModules: cache, dtype, loaders, rollout targets.

    Subclasses implement :meth:`generate` (returning the float64 tensors listed in
    the module docstring), :meth:`cache_params` and the property ``state_dim``, and
    may set ``self.system`` (a :class:`~hnn_pl.systems.base.HamiltonianSystem`
    whose ``energy`` the rollout metrics use).

    Args:
        batch_size: training rows per optimiser step over all processes (DDP splits
            it, see :class:`TensorBatches`); ``None``: the whole set.
        full_batch_steps: with ``batch_size=None``, training steps per epoch.
        seed: seeds generation and training order; ``None`` follows the run's
            ``seed_everything`` (``PL_GLOBAL_SEED``, else 0), so each seed draws its
            own data set, as the reference code does.
        cache_dir: where generated data is kept (default :func:`default_cache_dir`).
        dtype: ``"float32"`` or ``"float64"``, the dtype of the tensors served.
        window: ``None``: loaders serve derivative pairs ``(x, dx)``. ``K ≥ 2``:
            they serve windows of ``K`` consecutive observed samples as ``(y (B, K,
            D), t (B, K), index (B, K))``, ``index`` the rows of the split's
            ``obs_*`` table (state tasks only).
        keep_fraction: in ``(0, 1]``: keep a random ``max(2, ⌈keep_fraction · n⌉)``
            of each trajectory's ``n`` observed samples, in time order (irregular
            times), in both splits; drawn from a generator of its own (seed
            ``seed + THIN_SEED_OFFSET``), so the data draws do not change. The
            derivative pairs and the rollout targets are never thinned.
        observe: ``"states"``: the ``obs_*`` tables hold ``(q, p)``; ``"positions"``:
            ``q`` alone, ``(S, k)`` (what a camera or an encoder records; the momenta
            are learned, see :class:`~hnn_pl.models.base.DynamicsModel`), drawn from
            the same data; the derivative pairs are then made from the positions
            alone (:func:`~hnn_pl.data.differences.position_pairs`). The rollout
            targets keep the truth.
    """

    system = None

    def __init__(
        self,
        batch_size: int | None = None,
        full_batch_steps: int = 100,
        seed: int | None = None,
        cache_dir: str | None = None,
        dtype: str = "float32",
        window: int | None = None,
        keep_fraction: float = 1.0,
        observe: str = "states",
    ) -> None:
        super().__init__()
        require(observe in OBSERVE, f"observe must be one of {OBSERVE}, got {observe!r}")
        if dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
        require(
            batch_size is None or batch_size >= 1, f"batch_size must be >= 1 or null: {batch_size}"
        )
        require(full_batch_steps >= 1, f"full_batch_steps must be >= 1: {full_batch_steps}")
        require(window is None or window >= 2, f"window must be >= 2 or null: {window}")
        require(
            math.isfinite(keep_fraction) and 0 < keep_fraction <= 1,
            f"keep_fraction must lie in (0, 1]: {keep_fraction}",
        )
        self.window = window
        self.keep_fraction = float(keep_fraction)
        self.observe = observe
        self.batch_size = batch_size
        self.full_batch_steps = full_batch_steps
        self.seed = int(os.environ.get("PL_GLOBAL_SEED", 0)) if seed is None else seed
        self.cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.dtype = getattr(torch, dtype)
        self.data: dict[str, Tensor] | None = None
        self._rollout_cache: dict[tuple, tuple[Tensor, Tensor]] = {}
        self.save_hyperparameters(ignore=["system", "cache_dir"])  # the subclass's options too

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

    def _cache_params(self) -> dict[str, Any]:
        return {"class": type(self).__name__, "version": CACHE_VERSION, **self.cache_params()}

    @property
    def cache_path(self) -> Path:
        """``cache_dir/<ClassName>-<hash of cache_params>.pt``."""
        params = json.dumps(self._cache_params(), sort_keys=True, default=str)
        key = hashlib.sha256(params.encode()).hexdigest()
        return self.cache_dir / f"{type(self).__name__}-{key[:16]}.pt"

    def prepare_data(self) -> None:
        """Generate and cache the data set unless a valid cache already holds it.

        A cache file holds ``{"data", "params", "sha256"}``: the tensors, the
        parameters that made them and a SHA-256 of their bytes. A file that cannot
        be read, or whose parameters or checksum disagree, is reported and rebuilt.
        Files are written whole (a temporary file renamed into place; a failure,
        such as a full disk, leaves no partial file).
        """
        self.load_data()

    def load_data(self) -> dict[str, Tensor]:
        """The cached float64 tensors, generated and cached first if missing or bad."""
        data = self._load_cache()
        if data is None:
            data = self.generate()
            self._write_cache(data)
        return data

    def _write_cache(self, data: dict[str, Tensor]) -> None:
        path = self.cache_path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            if err.errno == errno.ENOSPC:
                raise no_space(path) from None
            raise
        params = json.loads(json.dumps(self._cache_params(), default=str))
        save_atomic({"data": data, "params": params, "sha256": tensors_digest(data)}, path)

    def _load_cache(self) -> dict[str, Tensor] | None:
        """The cached tensors, or ``None`` (with a warning if a file was there but bad)."""
        path = self.cache_path
        if not path.exists():
            return None
        try:
            payload = torch.load(path, weights_only=True)
            data = payload["data"]
            params = json.loads(json.dumps(self._cache_params(), default=str))
            if payload["params"] != params:
                problem = f"it was made with other parameters ({payload['params']})"
            elif payload["sha256"] != tensors_digest(data):
                problem = "its checksum does not match its contents"
            else:
                return data
        except Exception as err:  # truncated, garbage, empty, an older format
            first_line = (str(err).strip().splitlines() or [""])[0][:120]
            problem = f"it cannot be read ({type(err).__name__}: {first_line})"
        warnings.warn(f"data cache {path}: {problem}; rebuilding it", stacklevel=3)
        return None

    def setup(self, stage: str | None = None) -> None:
        """Load the cached data (generating it if needed) in the served dtype."""
        if self.data is not None:
            return
        self.data = served(self.load_data(), self.dtype, type(self).__name__)
        if self.observe == "positions":
            self.data.update(positions_only(self.data, self.state_dim // 2))
        for key, value in self.data.items():
            setattr(self, key, value)
        if "obs_y_train" in self.data:
            self._observe()
        elif self.window is not None or self.keep_fraction != 1.0:
            raise ValueError(f"{type(self).__name__} serves no observed trajectories: window: null")

    def _observe(self) -> None:
        """Thin the ``obs_*`` tables (``keep_fraction``) and index their windows."""
        g = self._generator(THIN_SEED_OFFSET)
        self._windowed: dict[str, tuple[Tensor, Tensor, Tensor]] = {}
        for split in ("train", "test"):
            y, t, traj = (getattr(self, f"obs_{k}_{split}") for k in ("y", "t", "traj"))
            if self.keep_fraction != 1.0:
                keep = thin(traj, self.keep_fraction, g)
                y, t, traj = y[keep], t[keep], traj[keep]
                for k, v in (("y", y), ("t", t), ("traj", traj)):
                    setattr(self, f"obs_{k}_{split}", v)
            setattr(self, f"n_{split}_trajectories", int(traj.max()) + 1 if len(traj) else 0)
            windows = None
            if self.window is not None:
                windows = window_starts(traj, self.window)
                require(
                    len(windows) > 0,
                    f"window {self.window} is longer than every {split} trajectory "
                    f"(at most {int(torch.bincount(traj).max())} samples)",
                )
                self._windowed[split] = (y[windows], t[windows], windows)
            setattr(self, f"windows_{split}", windows)

    def _generator(self, offset: int = 0) -> torch.Generator:
        return torch.Generator().manual_seed(self.seed + offset)

    def train_dataloader(self) -> TensorBatches:
        """Shuffled training batches; under data parallelism this rank's share of each
        global batch of ``batch_size`` rows (see :class:`TensorBatches`)."""
        rank, world = data_parallel_rank(self.trainer)
        seed = self.seed
        if world > 1 and self.trainer is not None:
            seed = self.trainer.strategy.broadcast(seed)  # one permutation for all ranks
        return TensorBatches(
            self._served("train"),
            self.batch_size,
            shuffle=True,
            generator=torch.Generator().manual_seed(seed + 1),
            repeats=self.full_batch_steps,
            rank=rank,
            world_size=world,
        )

    def val_dataloader(self) -> TensorBatches:
        """Held-out batches, sharded like training ones (torchmetrics sums over ranks,
        so ``val/loss`` is the MSE over the whole split)."""
        return TensorBatches(self._served("test"), self.batch_size, **self._ranks())

    def test_dataloader(self) -> TensorBatches:
        """As :meth:`val_dataloader`."""
        return TensorBatches(self._served("test"), self.batch_size, **self._ranks())

    def _served(self, split: str) -> tuple[Tensor, ...]:
        """``(x, dx)`` pairs, or with ``window`` the windows ``(y, t, index)``."""
        if self.window is not None:
            return self._windowed[split]
        return getattr(self, f"x_{split}"), getattr(self, f"dx_{split}")

    def predict_dataloader(self) -> TensorBatches:
        """All held-out inputs, unsharded: rank zero holds all for the writer."""
        return TensorBatches((self.x_test,), self.batch_size)

    def _ranks(self) -> dict[str, int]:
        rank, world = data_parallel_rank(self.trainer)
        return {"rank": rank, "world_size": world}

    @property
    def has_energy(self) -> bool:
        """Whether :meth:`energy` is defined (``system`` set): else rollouts skip the
        energy metrics."""
        return self.system is not None

    def energy(self, y: Tensor) -> Tensor:
        """The physical energy of states ``(..., D) -> (...)`` that metrics compare."""
        if self.system is None:
            raise NotImplementedError(f"{type(self).__name__} defines no energy")
        return self.system.energy(y)

    def true_field(self, t: Tensor, y: Tensor) -> Tensor:
        """The true ``dy/dt`` at held-out states ``y (T, B, D)`` at times ``t (T,)``: the
        system's field (the field error of :mod:`hnn_pl.evaluation` compares a model's
        with it)."""
        if self.system is None:
            raise NotImplementedError(f"{type(self).__name__} defines no true field")
        return self.system.vector_field(t, y)

    def reference_inputs(self, n: int | None = None) -> Tensor:
        """The first ``n`` training inputs ``(n, D)`` (all for ``None``): the states over
        which the spread of a learned ``H_θ`` is measured."""
        self.setup()
        return self.x_train[:n]

    def rollout_target(
        self, t_end: float | None = None, n_points: int | None = None, max_starts: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """``t (T,)``, ``y (T, B, D)``: the held-out trajectories (``t_end=None``) or the
        system's float64 truth from their starts on ``linspace(t₀, t_end, n_points)``
        (computed once per horizon, and only from the first ``max_starts`` starts, all for
        ``None``: a protocol that scores 100 of the three-body's 1,000 held-out
        trajectories integrates 100), in the served dtype; ``B`` at most ``max_starts``."""
        if t_end is None:
            return self.test_t, self.test_y[:, :max_starts]
        n = len(self.test_y[0]) if max_starts is None else min(int(max_starts), len(self.test_y[0]))
        key = (float(t_end), int(n_points or len(self.test_t)))
        if key not in self._rollout_cache or self._rollout_cache[key][1].shape[1] < n:
            t = torch.linspace(float(self.test_t[0]), key[0], key[1], dtype=torch.float64)
            y = self.system.trajectory(self.test_y[0, :n].to(torch.float64), t)
            self._rollout_cache[key] = (t.to(self.dtype), y.to(self.dtype))
        t, y = self._rollout_cache[key]
        return t, y[:, :n]


#: offset of the thinning generator's seed from ``seed`` (the data draws use ``seed``,
#: the training order ``seed + 1``)
THIN_SEED_OFFSET = 7919


def observed_table(y: Tensor, t: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``M`` trajectories sampled at common times, ``y (T, M, D)`` over ``t (T,)``, as
    the flat ``obs_*`` table: ``y (M·T, D)``, ``t (M·T,)``, ``traj (M·T,)`` int64,
    trajectory by trajectory (the derivative pairs' row order)."""
    n_t, m = y.shape[:2]
    rows = y.transpose(0, 1).reshape(-1, y.shape[-1])
    return rows, t.repeat(m), torch.arange(m).repeat_interleave(n_t)


def thin(traj: Tensor, keep_fraction: float, generator: torch.Generator) -> Tensor:
    """Rows ``(S',)`` of a table with trajectory ids ``traj (S,)`` (contiguous) that keep
    a random ``max(2, ⌈keep_fraction · n⌉)`` (at most ``n``) of each trajectory's ``n``
    samples, in their order; one ``randperm`` per trajectory from ``generator``."""
    counts = torch.bincount(traj).tolist()
    starts = [0, *torch.tensor(counts).cumsum(0).tolist()[:-1]]
    kept = []
    for start, n in zip(starts, counts, strict=True):
        k = thinned_count(n, keep_fraction)
        kept.append(start + torch.randperm(n, generator=generator)[:k].sort().values)
    return torch.cat(kept)


#: what the ``obs_*`` tables hold (``observe``)
OBSERVE = ("states", "positions")


def positions_only(data: dict[str, Tensor], k: int) -> dict[str, Tensor]:
    """The tables of ``observe="positions"``: ``obs_y_{split}`` cut to their first ``k``
    columns, and the derivative pairs ``x_{split}``, ``dx_{split}`` made from those
    positions alone (:func:`~hnn_pl.data.differences.position_pairs`: what a
    derivative fit, and ``H_θ``'s yardstick, can see). Raises ``ValueError`` for data
    without observed trajectories."""
    from hnn_pl.data.differences import position_pairs

    require("obs_y_train" in data, "observe: positions needs observed trajectories (obs_*)")
    out = {}
    for split in ("train", "test"):
        q = data[f"obs_y_{split}"][:, :k]
        out[f"obs_y_{split}"] = q
        x, dx = position_pairs(q, data[f"obs_t_{split}"], data[f"obs_traj_{split}"])
        out[f"x_{split}"], out[f"dx_{split}"] = x, dx
    return out


def thinned_count(n: int, keep_fraction: float) -> int:
    """Samples :func:`thin` keeps of a trajectory of ``n``: ``min(n, max(2, ⌈f · n⌉))``."""
    return min(n, max(2, math.ceil(keep_fraction * n)))


def served(data: dict[str, Tensor], dtype: torch.dtype, owner: str) -> dict[str, Tensor]:
    """``data``'s floating tensors in ``dtype`` (others as they are); a finite value the
    cast makes infinite raises ``ValueError`` naming the tensor and ``dtype: float64``."""
    out = {}
    for key, value in data.items():
        if not value.is_floating_point() or value.dtype == dtype:
            out[key] = value
            continue
        out[key] = value.to(dtype)
        overflow = torch.isinf(out[key]) & torch.isfinite(value)
        if overflow.any():
            v = float(value[overflow].flatten()[0])
            raise ValueError(
                f"{owner}: {key} holds {v:g}, beyond {str(dtype).removeprefix('torch.')} (largest "
                f"{torch.finfo(dtype).max:.4g}), the dtype it is served in: "
                "set data.init_args.dtype: float64"
            )
    return out


def window_starts(traj: Tensor, k: int) -> Tensor:
    """``(W, K)`` int64 rows ``s … s + K − 1`` of a table with contiguous trajectory ids
    ``traj (S,)``, for every ``s`` whose ``K`` samples share one trajectory."""
    s = torch.arange(max(len(traj) - k + 1, 0))
    s = s[traj[s] == traj[s + k - 1]]
    return s[:, None] + torch.arange(k)


def tensors_digest(data: dict[str, Tensor]) -> str:
    """SHA-256 over the names, dtypes, shapes and bytes of ``data``'s tensors."""
    digest = hashlib.sha256()
    for key in sorted(data):
        value = data[key].detach().cpu().contiguous()
        digest.update(f"{key}:{value.dtype}:{tuple(value.shape)}".encode())
        digest.update(value.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def require(condition: bool, message: str) -> None:
    """Raise ``ValueError(message)`` unless ``condition``: arguments are checked when an
    object is built, before any data, directory or log is made."""
    if not condition:
        raise ValueError(message)


def split_sizes(n: int, test_fraction: float) -> int:
    """Held-out count ``round(test_fraction · n)``, checked to leave both splits
    non-empty."""
    require(n >= 2, f"n_trajectories must be >= 2 (one to train, one to test): {n}")
    require(0 < test_fraction < 1, f"test_fraction must lie in (0, 1): {test_fraction}")
    n_test = round(test_fraction * n)
    require(
        0 < n_test < n,
        f"test_fraction {test_fraction} of {n} trajectories holds out {n_test}: "
        "need at least one in each split",
    )
    return n_test
