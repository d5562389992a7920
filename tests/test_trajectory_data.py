"""Observed trajectories: the same draws as the derivative pairs, windows, thinning."""

from __future__ import annotations

import math

import pytest
import torch
from test_bad_input import FIT, _fails

from hnn_pl.data import SimulatedData, TensorBatches
from hnn_pl.data.base import THIN_SEED_OFFSET, thin, window_starts
from hnn_pl.systems import MassSpring, TwoBody


def _spring(tmp_path, **kw) -> SimulatedData:
    dm = SimulatedData(MassSpring(), cache_dir=str(tmp_path), **{"dtype": "float64", **kw})
    dm.setup()
    return dm


def test_observed_tables_are_the_pairs_noisy_states(tmp_path):
    dm = _spring(tmp_path)
    assert torch.equal(dm.obs_y_train, dm.x_train) and torch.equal(dm.obs_y_test, dm.x_test)
    assert dm.n_train_trajectories == dm.n_test_trajectories == 25
    assert torch.equal(dm.obs_traj_train, torch.arange(25).repeat_interleave(30))
    t = torch.linspace(0.0, 3.0, 30, dtype=torch.float64)
    assert torch.equal(dm.obs_t_train, t.repeat(25)) and torch.equal(dm.obs_t_test, t.repeat(25))
    assert dm.obs_traj_train.dtype == torch.int64 and dm.windows_train is None
    clean = dm.test_y.transpose(0, 1).reshape(-1, 2)  # the held-out truth, row for row
    assert 0.09 < (dm.obs_y_test - clean).std() < 0.11


def test_window_option_leaves_the_pair_data_unchanged(tmp_path):
    pairs = _spring(tmp_path / "a", seed=4)
    windows = _spring(tmp_path / "b", seed=4, window=5, keep_fraction=0.5)
    for key in ("x_train", "dx_train", "x_test", "dx_test", "test_t", "test_y"):
        assert torch.equal(getattr(pairs, key), getattr(windows, key)), key
    assert pairs.cache_path.name == windows.cache_path.name  # not part of the draws


@pytest.mark.parametrize("k", [2, 5, 30])
def test_windows_never_cross_trajectories(tmp_path, k):
    dm = _spring(tmp_path, window=k)
    for split in ("train", "test"):
        w = getattr(dm, f"windows_{split}")
        traj = getattr(dm, f"obs_traj_{split}")
        assert w.shape == (25 * (30 - k + 1), k) and w.dtype == torch.int64
        assert (traj[w] == traj[w[:, :1]]).all()
        assert (w[:, 1:] - w[:, :-1] == 1).all()
        assert (getattr(dm, f"obs_t_{split}")[w].diff(dim=1) > 0).all()


def test_window_loaders_yield_states_times_and_rows(tmp_path):
    dm = _spring(tmp_path, window=4, full_batch_steps=3)
    batches = list(dm.train_dataloader())
    assert len(batches) == 3 and all(b is batches[0] for b in batches)
    y, t, index = batches[0]
    assert y.shape == (25 * 27, 4, 2) and t.shape == index.shape == (25 * 27, 4)
    assert torch.equal(y, dm.obs_y_train[index]) and torch.equal(t, dm.obs_t_train[index])
    (val,) = list(dm.val_dataloader())
    assert torch.equal(val[0], dm.obs_y_test[val[2]]) and torch.equal(val[1], dm.obs_t_test[val[2]])

    mini = _spring(tmp_path, window=4, batch_size=100, dtype="float32")
    loader = mini.train_dataloader()
    epoch = list(loader)
    assert len(loader) == len(epoch) == math.ceil(675 / 100)
    assert epoch[0][0].dtype == epoch[0][1].dtype == torch.float32
    assert epoch[0][2].dtype == torch.int64
    seen = torch.cat([b[2][:, 0] for b in epoch]).sort().values
    assert torch.equal(seen, mini.windows_train[:, 0])  # every window once per epoch
    for y, t, index in epoch:
        assert torch.equal(y, mini.obs_y_train[index]) and torch.equal(t, mini.obs_t_train[index])


def test_window_batches_shard_like_pairs(tmp_path):
    dm = _spring(tmp_path, window=3, batch_size=64)
    shards = []
    for rank in range(2):
        g = torch.Generator().manual_seed(1)
        batches = TensorBatches(dm._served("train"), 64, True, g, rank=rank, world_size=2)
        shards.append([b[2] for b in batches])
    for a, b in zip(*shards, strict=True):
        assert abs(len(a) - len(b)) <= 1 and not set(a[:, 0].tolist()) & set(b[:, 0].tolist())
    seen = torch.cat([w[:, 0] for shard in shards for w in shard]).sort().values
    assert torch.equal(seen, dm.windows_train[:, 0])


@pytest.mark.parametrize("fraction", [0.5, 0.2, 0.01])
def test_thinning_keeps_sorted_times_and_at_least_two(tmp_path, fraction):
    dm = _spring(tmp_path, keep_fraction=fraction, window=2)
    full = _spring(tmp_path)
    for split in ("train", "test"):
        traj = getattr(dm, f"obs_traj_{split}")
        counts = torch.bincount(traj)
        assert (counts == max(2, math.ceil(fraction * 30))).all() and len(counts) == 25
        t = getattr(dm, f"obs_t_{split}")
        same = traj[1:] == traj[:-1]
        assert (t[1:][same] > t[:-1][same]).all()
        # every kept sample is an observed one, at its own time
        t_full = getattr(full, f"obs_t_{split}")
        y_full = getattr(full, f"obs_y_{split}")
        rows = traj * 30 + torch.round(t / (3.0 / 29)).long()
        assert torch.equal(getattr(dm, f"obs_y_{split}"), y_full[rows])
        assert torch.equal(t, t_full[rows])


def test_thinning_is_seed_driven_and_irregular(tmp_path):
    a = _spring(tmp_path / "a", keep_fraction=0.5)
    b = _spring(tmp_path / "b", keep_fraction=0.5)
    c = _spring(tmp_path / "c", keep_fraction=0.5, seed=1)
    assert torch.equal(a.obs_t_train, b.obs_t_train) and torch.equal(a.obs_y_train, b.obs_y_train)
    assert not torch.equal(a.obs_t_train, c.obs_t_train)
    gaps = a.obs_t_train.diff()[a.obs_traj_train[1:] == a.obs_traj_train[:-1]]
    assert len(torch.unique(torch.round(gaps * 1e6))) > 3  # uneven spacing
    g = torch.Generator().manual_seed(a.seed + THIN_SEED_OFFSET)  # not the data's generator
    rows = thin(torch.arange(25).repeat_interleave(30), 0.5, g)
    assert torch.equal(a.obs_y_train, a.x_train[rows])


def test_window_starts_on_uneven_trajectories():
    traj = torch.tensor([0, 0, 0, 1, 1, 2, 2, 2, 2])
    assert window_starts(traj, 3).tolist() == [[0, 1, 2], [5, 6, 7], [6, 7, 8]]
    assert window_starts(traj, 2)[:, 0].tolist() == [0, 1, 3, 5, 6, 7]
    assert window_starts(traj, 10).shape == (0, 10)


def test_n_body_serves_windows_of_its_noise_free_states(tmp_path):
    dm = SimulatedData(
        TwoBody(),
        n_trajectories=10,
        t_span=(0.0, 20.0),
        n_points=50,
        noise_std=0.0,
        test_fraction=0.2,
        test_first=True,
        cache_dir=str(tmp_path),
        dtype="float64",
        window=6,
    )
    dm.setup()
    assert dm.n_train_trajectories == 8 and dm.n_test_trajectories == 2
    y, t, index = next(iter(dm.val_dataloader()))
    assert y.shape == (2 * 45, 6, 8)
    clean = dm.test_y.transpose(0, 1).reshape(-1, 8)
    torch.testing.assert_close(y, clean[index])


def test_a_window_longer_than_every_trajectory_is_refused(tmp_path):
    dm = SimulatedData(MassSpring(), cache_dir=str(tmp_path), window=31)
    with pytest.raises(ValueError, match="window 31 is longer than every train trajectory"):
        dm.setup()


@pytest.mark.parametrize(
    ("option", "expected"),
    [
        ("--data.init_args.window=1", "window must be >= 2"),
        ("--data.init_args.keep_fraction=0", "keep_fraction must lie in (0, 1]"),
        ("--data.init_args.keep_fraction=1.5", "keep_fraction must lie in (0, 1]"),
    ],
)
def test_bad_trajectory_options_fail_with_one_line(option, expected, capsys, monkeypatch, tmp_path):
    assert expected in _fails([*FIT, option], capsys, monkeypatch, tmp_path)


def test_thinning_uneven_trajectories_keeps_its_share_of_each():
    traj = torch.tensor([0] * 3 + [1] * 10 + [2] * 2 + [3] * 7)
    g = torch.Generator().manual_seed(0)
    rows = thin(traj, 0.5, g)
    assert torch.bincount(traj[rows]).tolist() == [2, 5, 2, 4]
    assert (rows.diff() > 0).all()  # kept in their order: times stay sorted
    assert torch.equal(rows, thin(traj, 0.5, torch.Generator().manual_seed(0)))
    assert torch.equal(thin(traj, 1.0, g), torch.arange(len(traj)))
