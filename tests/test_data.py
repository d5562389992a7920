"""Simulated data: the reference's shapes and splits, noise, determinism, cache."""

from __future__ import annotations

import warnings

import pytest
import torch

from hnn_pl.data import SimulatedData, TensorBatches
from hnn_pl.systems import MassSpring, Pendulum


def _spring(tmp_path, **kw) -> SimulatedData:
    return SimulatedData(MassSpring(), cache_dir=str(tmp_path), **kw)


@pytest.mark.parametrize(
    ("system", "n_points", "rows"), [(MassSpring(), 30, 750), (Pendulum(), 45, 1125)]
)
def test_shapes_and_split_match_the_reference(tmp_path, system, n_points, rows):
    dm = SimulatedData(system, n_points=n_points, cache_dir=str(tmp_path), dtype="float64")
    dm.setup("fit")
    assert dm.x_train.shape == dm.dx_train.shape == (rows, 2)
    assert dm.x_test.shape == dm.dx_test.shape == (rows, 2)
    assert dm.test_y.shape == (n_points, 25, 2) and dm.test_t.shape == (n_points,)
    assert dm.x_train.dtype == torch.float64
    clean = dm.test_y.transpose(0, 1).reshape(-1, 2)
    torch.testing.assert_close(dm.dx_test, system.vector_field(None, clean))
    noise = dm.x_test - clean
    assert 0.09 < noise.std() < 0.11 and abs(noise.mean()) < 0.01
    torch.testing.assert_close(
        system.hamiltonian(dm.test_y), system.hamiltonian(dm.test_y[0]).expand(n_points, -1)
    )


def test_test_split_is_the_last_trajectories(tmp_path):
    dm = _spring(tmp_path, noise_std=0.0, dtype="float64")
    dm.setup()
    first = dm.test_y[:, 0]
    torch.testing.assert_close(dm.x_test[:30], first)
    assert not torch.isclose(dm.x_train[:30], first).all()
    front = _spring(tmp_path, noise_std=0.0, test_first=True, test_fraction=0.2, dtype="float64")
    front.setup()
    assert front.test_y.shape[1] == 10 and front.x_train.shape[0] == 40 * 30


def test_generation_is_deterministic_and_seeded(tmp_path):
    a, b = _spring(tmp_path / "a"), _spring(tmp_path / "b")
    c = _spring(tmp_path / "c", seed=1)
    for dm in (a, b, c):
        dm.setup()
    assert torch.equal(a.x_train, b.x_train) and torch.equal(a.test_y, b.test_y)
    assert not torch.equal(a.x_train, c.x_train)


def test_cache_is_reused_and_keyed_by_parameters(tmp_path, monkeypatch):
    first = _spring(tmp_path)
    first.setup()
    assert first.cache_path.exists()

    def fail(self):
        raise AssertionError("generated again despite the cache")

    monkeypatch.setattr(SimulatedData, "generate", fail)
    second = _spring(tmp_path)
    second.setup()
    assert torch.equal(first.x_train, second.x_train)
    assert _spring(tmp_path, noise_std=0.2).cache_path != first.cache_path
    assert _spring(tmp_path, seed=3).cache_path != first.cache_path
    with pytest.raises(AssertionError, match="generated again"):
        _spring(tmp_path, n_points=31).setup()


def test_full_batch_loader_yields_the_tensors_themselves():
    x, y = torch.randn(750, 2), torch.randn(750, 2)
    loader = TensorBatches((x, y), batch_size=None, shuffle=True)
    (batch,) = list(loader)
    assert batch[0] is x and batch[1] is y and len(loader) == 1


def test_minibatches_cover_every_row_once_per_epoch():
    x = torch.arange(1003.0)[:, None]
    loader = TensorBatches(
        (x,), batch_size=200, shuffle=True, generator=torch.Generator().manual_seed(0)
    )
    epochs = [torch.cat([b[0] for b in loader]) for _ in range(2)]
    assert len(loader) == 6
    for rows in epochs:
        assert torch.equal(rows.sort(0).values, x)
    assert not torch.equal(epochs[0], epochs[1])


def test_full_batch_epochs_repeat_the_batch(tmp_path):
    dm = _spring(tmp_path, full_batch_steps=7)
    dm.setup()
    loader = dm.train_dataloader()
    batches = list(loader)
    assert len(loader) == len(batches) == 7
    assert all(b[0] is dm.x_train for b in batches)
    mini = _spring(tmp_path, batch_size=100, full_batch_steps=7)
    mini.setup()
    assert len(mini.train_dataloader()) == 8


@pytest.mark.parametrize(
    "damage",
    [
        lambda b: b[: len(b) // 2],
        lambda b: b"garbage" * 100,
        lambda b: b"",
        lambda b: b[:-300] + bytes(300),
    ],
    ids=["truncated", "garbage", "empty", "zeroed-tail"],
)
def test_a_corrupt_cache_is_named_and_rebuilt(tmp_path, damage):
    first = _spring(tmp_path)
    first.setup()
    path = first.cache_path
    path.write_bytes(damage(path.read_bytes()))
    again = _spring(tmp_path)
    with pytest.warns(UserWarning, match=f"data cache {path}.*rebuilding"):
        again.setup()
    assert torch.equal(first.x_train, again.x_train)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _spring(tmp_path).setup()  # rebuilt: read back without complaint


def test_a_cache_with_a_wrong_checksum_or_parameters_is_rebuilt(tmp_path):
    first = _spring(tmp_path)
    first.setup()
    payload = torch.load(first.cache_path, weights_only=True)
    payload["data"]["x_train"][0, 0] += 1.0
    torch.save(payload, first.cache_path)
    with pytest.warns(UserWarning, match="checksum"):
        _spring(tmp_path).setup()
    payload = torch.load(first.cache_path, weights_only=True)
    payload["params"]["noise_std"] = 0.5
    torch.save(payload, first.cache_path)
    with pytest.warns(UserWarning, match="other parameters"):
        _spring(tmp_path).setup()
