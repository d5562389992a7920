"""Data parallelism: the loaders shard every global batch by rank, and a 2-process CPU
DDP fit equals a 1-process fit at the same global batch.

The DDP run is this file run as a script (``python tests/test_ddp.py OUT``), as a
user would launch one: Lightning's DDP launcher re-runs the script for rank 1, which
does not work from inside pytest.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import lightning as L
import pytest
import torch

from hnn_pl.data import SimulatedData, TensorBatches
from hnn_pl.data.base import data_parallel_rank
from hnn_pl.models import HNN, Baseline
from hnn_pl.systems import MassSpring

# ---------------------------------------------------------------- sharding, no processes


def _expected_batches(n: int, batch_size: int | None, world: int) -> list[tuple[int, int]]:
    """The global batches' ``(start, stop)``: a tail of fewer than ``world`` rows joins
    the batch before it."""
    size = n if batch_size is None else min(batch_size, n)
    bounds = [(s, min(s + size, n)) for s in range(0, n, size)]
    if len(bounds) > 1 and bounds[-1][1] - bounds[-1][0] < world:
        bounds[-2:] = [(bounds[-2][0], n)]
    return bounds


def _loaders(n, batch_size, world, shuffle=True, repeats=1):
    x = torch.arange(float(n))[:, None]
    loaders = [
        TensorBatches(
            (x, -x),
            batch_size,
            shuffle=shuffle,
            generator=torch.Generator().manual_seed(7),
            repeats=repeats,
            rank=rank,
            world_size=world,
        )
        for rank in range(world)
    ]
    return x, loaders


@pytest.mark.parametrize("world", [1, 2, 3, 4])
@pytest.mark.parametrize(
    ("n", "batch_size"), [(1003, 200), (1000, 200), (1001, 200), (601, None), (10, 4)]
)
def test_shards_partition_every_global_batch(n, batch_size, world):
    """Each step the ranks' rows are disjoint, nearly equal, none empty, and in rank
    order are the global batch of one shared permutation; an epoch covers every row
    once; every rank has the same number of batches."""
    x, loaders = _loaders(n, batch_size, world)
    bounds = _expected_batches(n, batch_size, world)
    gen = torch.Generator().manual_seed(7)
    assert {len(loader) for loader in loaders} == {len(bounds)}
    for _epoch in range(2):  # a new permutation each epoch, the same on every rank
        perm = torch.randperm(n, generator=gen) if batch_size is not None else torch.arange(n)
        steps = list(zip(*loaders, strict=True))
        assert len(steps) == len(bounds)
        for shards, (start, stop) in zip(steps, bounds, strict=True):
            rows = [s[0][:, 0] for s in shards]
            sizes = [len(r) for r in rows]
            assert min(sizes) >= 1 and max(sizes) - min(sizes) <= 1
            assert torch.equal(torch.cat(rows), x[perm[start:stop], 0])
            assert all(torch.equal(s[1], -s[0]) for s in shards)  # tensors stay paired
        epoch = torch.cat([s[0][:, 0] for shards in steps for s in shards])
        assert torch.equal(epoch.sort().values, x[:, 0])


@pytest.mark.parametrize("world", [2, 4])
def test_ranks_together_see_the_one_process_batches(world):
    """Without a merged tail, the ranks' shards, concatenated, are exactly the batches
    one process sees with the same seed (mini-batches of 200 of 1000 rows)."""
    _, (single,) = _loaders(1000, 200, 1)
    _, loaders = _loaders(1000, 200, world)
    for _epoch in range(2):
        for one, *shards in zip(single, *loaders, strict=True):
            assert torch.equal(one[0], torch.cat([s[0] for s in shards]))
            assert {len(s[0]) for s in shards} == {200 // world}


def test_full_batch_shard_is_one_block_view_repeated():
    x, loaders = _loaders(601, None, 2, repeats=3)
    blocks = [[b[0] for b in loader] for loader in loaders]
    assert len(blocks[0]) == len(blocks[1]) == 3
    assert all(b is block[0] for block in blocks for b in block)  # no work per step
    r0, r1 = blocks[0][0], blocks[1][0]
    assert torch.equal(r0, x[:300]) and torch.equal(r1, x[300:])
    assert r0.data_ptr() == x.data_ptr() and r1.data_ptr() == x[300:].data_ptr()
    (single,) = _loaders(601, None, 1, repeats=3)[1]
    assert next(iter(single))[0] is single.tensors[0]  # one process: the tensors themselves


def test_impossible_shardings_are_refused():
    x = torch.zeros(10, 2)
    with pytest.raises(ValueError, match="rank"):
        TensorBatches((x,), 5, rank=2, world_size=2)
    with pytest.raises(ValueError, match="at least as many rows"):
        TensorBatches((x,), 1, world_size=2)
    with pytest.raises(ValueError, match="at least as many rows"):
        TensorBatches((x[:3],), None, world_size=4)


def _stub_trainer(rank=1, world=3, broadcast=lambda obj: obj):
    kwargs = {"rank": rank, "num_replicas": world} if world else None
    return SimpleNamespace(
        distributed_sampler_kwargs=kwargs, strategy=SimpleNamespace(broadcast=broadcast)
    )


def test_rank_comes_from_the_trainer(tmp_path):
    assert data_parallel_rank(None) == (0, 1)
    assert data_parallel_rank(_stub_trainer(1, 3)) == (1, 3)
    assert data_parallel_rank(_stub_trainer(world=None)) == (0, 1)  # single device
    assert data_parallel_rank(L.Trainer(accelerator="cpu", devices=1, logger=False)) == (0, 1)

    dm = SimulatedData(MassSpring(), n_trajectories=4, batch_size=20, cache_dir=str(tmp_path))
    dm.setup()
    dm.trainer = _stub_trainer(1, 3)
    for loader in (dm.train_dataloader(), dm.val_dataloader(), dm.test_dataloader()):
        assert (loader.rank, loader.world_size, loader.batch_size) == (1, 3, 20)
    predict = dm.predict_dataloader()  # every rank predicts every row
    assert (predict.rank, predict.world_size) == (0, 1)


def test_rank_zero_seed_orders_every_rank(tmp_path):
    """The training permutation's seed is broadcast from rank zero, so ranks whose
    seeds differ still share one permutation."""
    dm = SimulatedData(
        MassSpring(), n_trajectories=4, batch_size=20, seed=5, cache_dir=str(tmp_path)
    )
    dm.setup()
    dm.trainer = _stub_trainer(0, 2, broadcast=lambda seed: 41)
    loader = dm.train_dataloader()
    perm = torch.randperm(len(dm.x_train), generator=torch.Generator().manual_seed(42))
    assert torch.equal(next(iter(loader))[0], dm.x_train[perm[:10]])


# ---------------------------------------------------------------- a real 2-process DDP fit

#: 10 training trajectories × 31 points = 310 rows (full batch: 155 per rank; batches of
#: 100: 100, 100, 100, 10, all even); 9 held-out ones = 279 rows (odd: uneven val shards)
DATA = dict(n_trajectories=19, test_fraction=0.45, n_points=31, full_batch_steps=5, seed=0)
CASES = {"hnn-full": (HNN, None), "hnn-mini": (HNN, 100), "baseline-mini": (Baseline, 100)}
STEPS = 8  # > one epoch in both modes: the second epoch's permutation is shared too
#: float64 throughout; the runs differ only in summation order (one mean over the global
#: batch vs the all-reduced mean of two half-batch means)
TOL = 1e-12


class RecordRows(L.Callback):
    """Keeps every training and validation batch's inputs this rank saw."""

    def __init__(self) -> None:
        self.train: list[torch.Tensor] = []
        self.val: list[torch.Tensor] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.train.append(batch[0].clone())

    def on_validation_batch_start(self, trainer, pl_module, batch, batch_idx, dataloader_idx=0):
        self.val.append(batch[0].clone())


def run_cases(out_dir: Path, devices: int) -> None:
    """Fit every case for :data:`STEPS` steps, validate, save what each rank saw."""
    for name, (cls, batch_size) in CASES.items():
        dm = SimulatedData(MassSpring(), batch_size=batch_size, dtype="float64", **DATA)
        torch.manual_seed(0)
        model = cls(input_dim=2, hidden_dim=16, lr=1e-2)
        record = RecordRows()
        trainer = L.Trainer(
            accelerator="cpu",
            devices=devices,
            strategy="ddp" if devices > 1 else "auto",
            precision="64-true",
            max_steps=STEPS,
            logger=False,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            num_sanity_val_steps=0,
            callbacks=[record],
        )
        trainer.fit(model, datamodule=dm)
        record.val.clear()  # only the validation below
        (metrics,) = trainer.validate(model, datamodule=dm, verbose=False)
        torch.save(
            {
                "params": {k: v.detach().clone() for k, v in model.state_dict().items()},
                "train": record.train,
                "val": record.val,
                "val_loss": float(metrics["val/loss"]),
                "steps": trainer.global_step,
            },
            out_dir / f"{name}-{devices}-rank{trainer.global_rank}.pt",
        )


@pytest.mark.slow
def test_two_process_ddp_fit_equals_one_process_fit(tmp_path):
    run_cases(tmp_path, devices=1)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
    env.pop("LOCAL_RANK", None)
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, __file__, str(tmp_path)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    print(f"2-process DDP run: {time.perf_counter() - start:.1f} s")

    for name in CASES:
        one = torch.load(tmp_path / f"{name}-1-rank0.pt", weights_only=True)
        ranks = [torch.load(tmp_path / f"{name}-2-rank{r}.pt", weights_only=True) for r in (0, 1)]
        assert one["steps"] == ranks[0]["steps"] == ranks[1]["steps"] == STEPS

        # each rank trained on its half of every global batch, together on all of it
        assert len(ranks[0]["train"]) == len(ranks[1]["train"]) == len(one["train"])
        for batch, r0, r1 in zip(one["train"], ranks[0]["train"], ranks[1]["train"]):
            assert len(r0) == len(r1) == len(batch) // 2
            assert torch.equal(torch.cat([r0, r1]), batch)
        # validation: each rank its share (uneven: 279 rows), the metric over all rows
        assert len(ranks[0]["val"]) == len(ranks[1]["val"]) == len(one["val"])
        for batch, r0, r1 in zip(one["val"], ranks[0]["val"], ranks[1]["val"]):
            assert abs(len(r0) - len(r1)) <= 1 and torch.equal(torch.cat([r0, r1]), batch)
        assert ranks[0]["val_loss"] == ranks[1]["val_loss"]
        # (torchmetrics keeps its sums in float32 whatever the model's dtype)
        assert ranks[0]["val_loss"] == pytest.approx(one["val_loss"], rel=1e-6)

        # the replicas agree exactly, and with the one-process fit to float64 round-off
        diff = 0.0
        for key, value in one["params"].items():
            assert value.dtype == torch.float64
            assert torch.equal(ranks[0]["params"][key], ranks[1]["params"][key])
            torch.testing.assert_close(ranks[0]["params"][key], value, rtol=0, atol=TOL)
            diff = max(diff, float((ranks[0]["params"][key] - value).abs().max()))
        print(f"{name}: max |θ_ddp − θ_1| = {diff:.2e}")


if __name__ == "__main__":  # the DDP run: rank 0 launches rank 1 with these arguments
    torch.set_num_threads(1)
    run_cases(Path(sys.argv[1]), devices=2)
