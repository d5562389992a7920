"""Recorded trajectories: the three file formats, their checks, splits and rollouts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_bad_input import FIT, _fails
from torch import nn

from hnn_pl import evaluation
from hnn_pl.commands.cli import cli_main
from hnn_pl.data import RealPendulumData, RecordingData, load_recording
from hnn_pl.evaluation import Protocol
from hnn_pl.systems import MassSpring
from hnn_pl.systems.real_pendulum import load_real_pendulum

PROTOCOL = Protocol(t_end=None, n_points=None, n_groups=1)


class TrueField(nn.Module):
    def __init__(self, system) -> None:
        super().__init__()
        self.system = system

    def vector_field(self, t, y):
        return self.system.vector_field(t, y)


def _recorded_springs(ids=(7, 2, 5), lengths=(12, 9, 15), seed=0):
    """Exact mass-spring states at uneven, different times per trajectory, rows
    interleaved: ``(id, t, y)`` rows as a file holds them."""
    g = torch.Generator().manual_seed(seed)
    spring, rows = MassSpring(), []
    for i, n in zip(ids, lengths, strict=True):
        t = torch.cumsum(0.05 + 0.3 * torch.rand(n, generator=g, dtype=torch.float64), 0)
        y = spring.trajectory(spring.sample_initial(1, g), t)[:, 0]
        rows += [(i, float(t[j]), y[j].tolist()) for j in range(n)]
    rows.sort(key=lambda r: r[1])  # interleave the trajectories by time
    return rows


def _write(path, rows):
    """``rows`` into ``path`` (.csv, .npz or .pt) in the documented format."""
    ids = np.array([r[0] for r in rows])
    t = np.array([r[1] for r in rows])
    y = np.array([r[2] for r in rows])
    if path.suffix == ".csv":
        k = y.shape[1] // 2
        names = ["trajectory", "time", *(f"q{i + 1}" for i in range(k))]
        names += [f"p{i + 1}" for i in range(k)]
        lines = [",".join(names)]
        lines += [",".join([str(i), repr(ti), *map(repr, yi)]) for i, ti, yi in rows]
        path.write_text("\n".join(lines) + "\n")
    elif path.suffix == ".npz":
        np.savez(path, trajectory=ids, t=t, y=y)
    else:
        torch.save(
            {"trajectory": torch.tensor(ids), "t": torch.tensor(t), "y": torch.tensor(y)}, path
        )
    return path


def test_csv_npz_and_pt_load_to_the_same_tensors(tmp_path):
    rows = _recorded_springs()
    recs = [load_recording(_write(tmp_path / f"r{s}", rows)) for s in (".csv", ".npz", ".pt")]
    first = recs[0]
    assert first.ids.tolist() == [2, 5, 7] and first.n_trajectories == 3
    assert torch.bincount(first.traj).tolist() == [9, 15, 12]
    assert first.y.dtype == first.t.dtype == torch.float64 and first.y.shape == (36, 2)
    for rec in recs[1:]:
        for key in ("traj", "t", "y", "ids"):
            assert torch.equal(getattr(rec, key), getattr(first, key)), key
    for a, b in first.bounds():  # each trajectory contiguous, in time order, exact states
        assert (first.t[a + 1 : b] > first.t[a : b - 1]).all()
        e = MassSpring().energy(first.y[a:b])
        torch.testing.assert_close(e, e[:1].expand(b - a), rtol=1e-12, atol=1e-12)


HEADER = "trajectory,time,q1,p1\n"


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("a.txt", HEADER, "unknown suffix '.txt'"),
        ("a.csv", None, "no such file"),
        ("a.csv", "", "empty"),
        ("a.csv", "id,t,q,p\n0,0,1,1\n", "line 1: header must be trajectory,time"),
        ("a.csv", "trajectory,time,q1\n0,0,1\n", "line 1: header must be"),
        ("a.csv", HEADER, "no samples after the header"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1\n", "line 3: 3 values, the header has 4"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,x,1\n", "line 3: 'x' is not a number"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,nan,1\n", "line 3: non-finite value"),
        ("a.csv", HEADER + "0,0,1,1\n0,inf,1,1\n", "line 3: non-finite value"),
        ("a.csv", HEADER + "0,0,1,1\n0.5,1,1,1\n", "line 3: trajectory id 0.5 is not an integer"),
        (
            "a.csv",
            HEADER + "0,0,1,1\n0,1,1,1\n0,1,2,2\n",
            "line 4: time 1.0 of trajectory 0 is not after",
        ),
        (
            "a.csv",
            HEADER + "0,2,1,1\n1,0,1,1\n0,1,1,1\n1,1,1,1\n",
            "line 4: time 1.0 of trajectory 0",
        ),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1,1\n3,0,1,1\n", "line 4: trajectory 3 has one sample"),
        ("a.csv", b"\xff\xfe\x00garbage", "not a text file"),
        ("a.pt", b"garbage" * 10, "cannot be read"),
        ("a.npz", b"garbage" * 10, "cannot be read"),
    ],
)
def test_each_bad_recording_gets_one_line_naming_file_and_row(tmp_path, name, content, expected):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(ValueError) as info:
        load_recording(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"recording {path}")
    assert expected in message, message


@pytest.mark.parametrize(
    ("arrays", "expected"),
    [
        ({"t": np.zeros(3), "y": np.zeros((3, 2))}, "missing trajectory"),
        ({"trajectory": np.zeros(3), "t": np.zeros(2), "y": np.zeros((3, 2))}, "t (2,)"),
        ({"trajectory": np.zeros(3), "t": np.arange(3.0), "y": np.zeros((3, 3))}, "even number"),
        ({"trajectory": np.zeros(3), "t": np.arange(3.0), "y": np.zeros(3)}, "shapes must be"),
        (
            {"trajectory": np.zeros(3), "t": np.array([0, 1, np.nan]), "y": np.zeros((3, 2))},
            "row 2: non-finite",
        ),
        (
            {"trajectory": np.zeros(3), "t": np.array([0.0, 2, 1]), "y": np.zeros((3, 2))},
            "row 2: time 1.0 of trajectory 0 is not after its previous sample's 2.0 (row 1)",
        ),
        (
            {"trajectory": np.array([0, 0, 1]), "t": np.arange(3.0), "y": np.zeros((3, 2))},
            "row 2: trajectory 1 has one sample",
        ),
    ],
)
@pytest.mark.parametrize("suffix", [".npz", ".pt"])
def test_bad_arrays_are_named_by_row(tmp_path, arrays, expected, suffix):
    path = tmp_path / f"a{suffix}"
    if suffix == ".npz":
        np.savez(path, **arrays)
    else:
        torch.save({k: torch.as_tensor(v) for k, v in arrays.items()}, path)
    with pytest.raises(ValueError) as info:
        load_recording(path)
    assert str(info.value).startswith(f"recording {path}") and expected in str(info.value)


def test_a_bad_recording_fails_the_cli_with_one_line(tmp_path_factory, capsys, monkeypatch):
    bad = tmp_path_factory.mktemp("recordings") / "bad.csv"
    bad.write_text(HEADER + "0,0,1,1\n0,0,1,1\n")
    run = tmp_path_factory.mktemp("run")
    config = run / "recording.yaml"
    config.write_text(
        f"data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n    path: {bad}\n"
    )
    line = _fails([*FIT, "--config", str(config)], capsys, monkeypatch, run)
    assert f"recording {bad}, line 3: time 0.0 of trajectory 0 is not after" in line


def test_split_by_trajectory_and_rollouts_on_the_union_of_times(tmp_path):
    rows = _recorded_springs(ids=(7, 2, 5, 9, 4), lengths=(12, 9, 15, 11, 10))
    path = _write(tmp_path / "springs.csv", rows)
    dm = RecordingData(str(path), MassSpring(), test_trajectories=[7, 2], window=3, dtype="float64")
    dm.setup()
    rec = load_recording(path)
    assert rec.ids.tolist() == [2, 4, 5, 7, 9]
    assert dm.n_train_trajectories == 3 and dm.n_test_trajectories == 2
    (a0, b0), (a2, b2) = rec.bounds()[0], rec.bounds()[3]
    torch.testing.assert_close(dm.obs_y_test, torch.cat([rec.y[a0:b0], rec.y[a2:b2]]))
    assert (dm.obs_traj_train[dm.windows_train] == dm.obs_traj_train[dm.windows_train[:, :1]]).all()
    t, y = dm.rollout_target(None)
    assert y.shape == (len(t), 2, 2) and t[0] == 0
    assert int((~y.isnan().any(-1)).sum()) == (b0 - a0) + (b2 - a2)
    metrics, r = evaluation.evaluate(TrueField(MassSpring()), dm, PROTOCOL)
    assert metrics["state_mse"] < 1e-14 and metrics["energy_mse"] < 1e-14
    assert abs(metrics["true_energy_drift_slope"]) < 1e-12 and metrics["diverged_rows"] == 0
    still = RecordingData(str(path), MassSpring(), test_trajectories=[7, 2], dtype="float64")
    still.setup()
    m_still, _ = evaluation.evaluate(Still(), still, PROTOCOL)
    assert m_still["state_mse"] > 0.1 and m_still["motion_error"] > 0.5
    with pytest.raises(ValueError, match="t_end: null"):
        dm.rollout_target(20.0)


class Still(nn.Module):
    def vector_field(self, t, y):
        return torch.zeros_like(y)


def test_one_recording_holds_out_a_time_segment_and_needs_no_energy(tmp_path):
    path = _write(tmp_path / "one.npz", _recorded_springs(ids=(0,), lengths=(40,)))
    rec = load_recording(path)
    a, b = float(rec.t[10]), float(rec.t[19])
    dm = RecordingData(str(path), test_segment=(a, b), window=4, dtype="float64")
    dm.setup()
    assert torch.equal(dm.obs_y_test, rec.y[10:20]) and torch.equal(dm.test_t, rec.t[10:20])
    assert torch.bincount(dm.obs_traj_train).tolist() == [10, 20]  # before and after
    assert dm.windows_train.shape == (7 + 17, 4)
    metrics, _ = evaluation.evaluate(TrueField(MassSpring()), dm, PROTOCOL)
    assert metrics["state_mse"] < 1e-14 and not any("energy" in k for k in metrics)
    last = RecordingData(str(path), test_fraction=0.25)
    last.setup()
    assert len(last.obs_t_test) == 10 and torch.bincount(last.obs_traj_train).tolist() == [30]


def test_central_differences_within_each_trajectory(tmp_path):
    path = _write(tmp_path / "s.pt", _recorded_springs())
    dm = RecordingData(str(path), test_fraction=0.34, dtype="float64")
    dm.setup()
    rec = load_recording(path)
    (a, b), (c, d), _ = rec.bounds()
    t, y = rec.t, rec.y
    expected = (y[a + 2 : b] - y[a : b - 2]) / (t[a + 2 : b] - t[a : b - 2])[:, None]
    assert dm.x_train.shape == ((b - a - 2) + (d - c - 2), 2)
    torch.testing.assert_close(dm.x_train[: b - a - 2], y[a + 1 : b - 1])
    torch.testing.assert_close(dm.dx_train[: b - a - 2], expected)
    # a field estimate: uneven central differences of a smooth orbit, ≈ J∇H to O(Δt²)
    err = (dm.dx_train - MassSpring().vector_field(None, dm.x_train)).abs().max()
    assert err < 0.2


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        ({"test_trajectories": [9]}, "no trajectory with id [9]"),
        ({"test_trajectories": [2, 5, 7]}, "at least one trajectory in each split"),
        ({"test_segment": (0.0, 1.0)}, "test_segment is for a single recording"),
        ({"test_fraction": 0.01}, "holds out 0"),
        ({"differences": "backward"}, "differences must be"),
        ({"window": 1}, "window must be >= 2"),
    ],
)
def test_bad_splits_are_refused_at_construction(tmp_path, kwargs, expected):
    path = _write(tmp_path / "s.csv", _recorded_springs())
    with pytest.raises(ValueError, match=expected.replace("[", r"\[").replace("]", r"\]")):
        RecordingData(str(path), **kwargs)


def test_the_real_pendulum_is_the_shipped_recording(tmp_path):
    t, y = load_real_pendulum()
    dm = RealPendulumData(dtype="float64", window=5)
    assert torch.equal(dm.recording.t, t) and torch.equal(dm.recording.y, y)
    dm.setup()
    assert torch.equal(dm.obs_y_test, y[444:554]) and torch.equal(dm.obs_t_test, dm.test_t)
    assert torch.bincount(dm.obs_traj_train).tolist() == [444, 2]
    txt = tmp_path / "copy.txt"
    txt.write_text(
        "%o v\n"
        + "\n".join(
            f"0 {a!r} {b!r} {c!r}" for a, (b, c) in zip(t.tolist(), y.tolist(), strict=True)
        )
    )
    again = RealPendulumData(str(txt), dtype="float64")
    again.setup()
    assert torch.equal(again.x_train, RealPendulumData(dtype="float64").load_data()["x_train"])
    central = RealPendulumData(dtype="float64", differences="central")
    central.setup()
    assert torch.equal(central.obs_t_test, t[445:555])
    assert torch.bincount(central.obs_traj_train).tolist() == [445]  # 555 alone: dropped
    assert math.isclose(float(central.test_t[0]), 81.0 + 1 / 6, rel_tol=1e-12)


def test_a_recording_thinned_and_windowed(tmp_path):
    path = _write(tmp_path / "s.npz", _recorded_springs(lengths=(12, 9, 15)))
    dm = RecordingData(str(path), test_fraction=0.34, window=3, keep_fraction=0.5)
    dm.setup()
    rec = load_recording(path)
    assert torch.bincount(dm.obs_traj_train).tolist() == [5, 8]  # ⌈9/2⌉, ⌈15/2⌉
    assert torch.bincount(dm.obs_traj_test).tolist() == [6]
    y, t, index = next(iter(dm.train_dataloader()))
    assert y.shape == (3 + 6, 3, 2) and (t.diff(dim=1) > 0).all()
    kept = torch.isin(rec.t.float(), dm.obs_t_train)
    assert int(kept.sum()) == 13


def test_the_cli_fits_a_recording(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = _write(tmp_path / "s.csv", _recorded_springs())
    config = tmp_path / "recording.yaml"
    config.write_text(
        "data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n"
        f"    path: {path}\n    test_fraction: 0.34\n    system: null\n"
        "trainer:\n  callbacks:\n    - class_path: hnn_pl.callbacks.RolloutCallback\n"
        "      init_args: {every_n_epochs: 0, overrides: {t_end: null, n_points: null}}\n"
    )
    args = ["--config=spring_fast.yaml", f"--config={config}", "--trainer.max_steps=2"]
    args += ["--trainer.logger=false", "--trainer.enable_checkpointing=false"]
    cli = cli_main([*args, "--trainer.enable_progress_bar=false"], run=False, save_config=False)
    cli.trainer.fit(cli.model, cli.datamodule)
    (logged,) = cli.trainer.test(cli.model, cli.datamodule, verbose=False)
    assert "rollout/state_mse" in logged and "rollout/energy_mse" not in logged
    assert math.isfinite(logged["rollout/state_mse"]) and math.isfinite(logged["test/loss"])
