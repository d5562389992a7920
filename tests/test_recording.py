"""Recorded trajectories: the three file formats, their checks, splits and rollouts."""

from __future__ import annotations

import gzip
import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from lightning.pytorch import Callback
from test_bad_input import FIT, _fails
from torch import nn

from hnn_pl import evaluation
from hnn_pl.callbacks import RolloutCallback
from hnn_pl.commands.cli import cli_main, quiet_args
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


def _recorded_springs(ids=(7, 2, 5), lengths=(12, 9, 15), seed=0, offset=0.0):
    """Exact mass-spring states at uneven, different times per trajectory (plus
    ``offset``), rows interleaved: ``(id, t, y)`` rows as a file holds them."""
    g = torch.Generator().manual_seed(seed)
    spring, rows = MassSpring(), []
    for i, n in zip(ids, lengths, strict=True):
        t = torch.cumsum(0.05 + 0.3 * torch.rand(n, generator=g, dtype=torch.float64), 0)
        y = spring.trajectory(spring.sample_initial(1, g), t)[:, 0]
        rows += [(i, float(t[j]) + offset, y[j].tolist()) for j in range(n)]
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
        for key in ("traj", "t", "y", "ids", "t0"):
            assert torch.equal(getattr(rec, key), getattr(first, key)), key
    for (a, b), i, t0 in zip(first.bounds(), first.ids.tolist(), first.t0.tolist(), strict=True):
        file_t = torch.tensor([r[1] for r in rows if r[0] == i], dtype=torch.float64)
        assert first.t[a] == 0 and t0 == file_t[0]  # each trajectory starts at 0, t0 kept
        torch.testing.assert_close(first.t[a:b] + t0, file_t, rtol=0, atol=1e-15)
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
        ("a.csv", "trajectory,time,q1,p2\n0,0,1,1\n", "line 1: header must be"),
        ("a.csv", "trajectory,time,q,q2\n0,0,1,1\n", "line 1: header must be"),
        ("a.csv", HEADER, "no samples after the header"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1\n", "line 3: 3 values, the header has 4"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,x,1\n", "line 3, column 3 (q1): 'x' is not a decimal"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,abc,1\n", "line 3, column 3 (q1): 'abc' is not a"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1, \n", "line 3, column 4 (p1): empty cell"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1_5,1\n", "line 3, column 3 (q1): '1_5' is not a"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,0x10,1\n", "line 3, column 3 (q1): '0x10' is not a"),
        ("a.csv", HEADER + "0,0,1,1\n0,1_0,1,1\n", "line 3, column 2 (time): '1_0' is not"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1,1 # c\n", "line 3, column 4 (p1): '1 # c' is not"),
        ("a.csv", HEADER + "a,0,1,1\na,1,1,1\n", "line 2, column 1 (trajectory): 'a' is not an"),
        ("a.csv", HEADER + "1_0,0,1,1\n", "line 2, column 1 (trajectory): '1_0' is not an"),
        ("a.csv", HEADER + "1e300,0,1,1\n1e300,1,1,1\n", "line 2: trajectory id 1e300 is beyond"),
        (
            "a.csv",
            HEADER + "3.0000000000000001,0,1,1\n",
            "line 2: trajectory id 3.0000000000000001 is not an integer",
        ),
        ("a.csv", HEADER + "9.3e18,0,1,1\n", "line 2: trajectory id 9.3e18 is beyond int64"),
        ("a.csv", HEADER + "0,0,1,1\nnan,1,1,1\n", "line 3: trajectory id nan is not an integer"),
        (
            "a.csv",
            HEADER + "9223372036854775808,0,1,1\n",
            "line 2: trajectory id 9223372036854775808 is beyond int64",
        ),
        ("a.csv", HEADER + "0,0,1,1\n0,1,1,1\n0,1,1,1,1\n", "line 4: 5 values, the header has 4"),
        ("a.csv", HEADER + "0,0,1,1\n0,1,nan,1\n", "line 3: non-finite value"),
        ("a.csv", HEADER + "0,0,1,1\n0,inf,1,1\n", "line 3: non-finite value"),
        ("a.csv", HEADER + "0,0,1,1\n0.5,1,1,1\n", "line 3: trajectory id 0.5 is not an integer"),
        ("a.csv", HEADER + "0,0,1,1\n\n0,1e400,1,1\n", "line 4: non-finite value"),
        ("a.csv", "# c\n" + HEADER + "\n0,0,1,1\n0,1,nan,1\n", "line 5: non-finite value"),
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
        ("a.csv", b"\xff\xfe\x00garbage", "line 1: not a text file (not UTF-8)"),
        ("a.csv", HEADER.encode() + b"0,0,1,1\n0,1,\xe9,1\n", "line 3: not a text file"),
        (
            "a.csv",
            gzip.compress(HEADER.encode(), mtime=0),
            "a gzip file, not a text file: decompress it",
        ),
        ("a.pt", b"garbage" * 10, "not a torch.save file of tensors (neither a zip archive nor"),
        ("a.pt", pickle.dumps([1, 2]), "not a torch.save file of tensors (damaged, or another"),
        ("a.pt", gzip.compress(b"x", mtime=0), "not a torch.save file of tensors (a gzip file)"),
        ("a.npz", b"garbage" * 10, "not an .npz archive of arrays (numpy.savez)"),
        (
            "a.npz",
            pickle.dumps({"trajectory": [0, 0]}),
            "not an .npz archive of arrays (numpy.savez): a Python pickle, which is never loaded",
        ),
        ("a.npz", b"PK\x03\x04" + b"garbage" * 10, "a damaged .npz archive"),
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
    assert not any(inner in message for inner in ("weights_only", "allow_pickle", "Error"))


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
        (
            {"trajectory": np.array([0, 0.5]), "t": np.arange(2.0), "y": np.zeros((2, 2))},
            "row 1: trajectory id 0.5 is not an integer",
        ),
        (
            {"trajectory": np.array([0, 2.0**60]), "t": np.arange(2.0), "y": np.zeros((2, 2))},
            "row 1: trajectory id 1.152921504606847e+18 is a float beyond ±2⁵³",
        ),
        (
            {
                "trajectory": np.array([1, 2**63, 2**63], dtype=np.uint64),
                "t": np.arange(3.0),
                "y": np.zeros((3, 2)),
            },
            "row 1: trajectory id 9223372036854775808 is beyond int64",
        ),
        (
            {"trajectory": np.array(["a", "a"]), "t": np.arange(2.0), "y": np.zeros((2, 2))},
            "row 0: trajectory id 'a' is text, not a number",
        ),
    ],
)
@pytest.mark.parametrize("suffix", [".npz", ".pt"])
def test_bad_arrays_are_named_by_row(tmp_path, arrays, expected, suffix):
    path = tmp_path / f"a{suffix}"
    if suffix == ".npz":
        np.savez(path, **arrays)
    else:  # torch has no text tensors: text as a list
        as_list = {k: v.tolist() for k, v in arrays.items() if v.dtype.kind == "U"}
        torch.save(
            {k: torch.as_tensor(v) for k, v in arrays.items() if k not in as_list} | as_list, path
        )
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
    a, b = float(rec.t[10] + rec.t0[0]), float(rec.t[19] + rec.t0[0])  # the file's times
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
    assert torch.equal(dm.recording.t, t) and torch.equal(dm.recording.y, y)  # not shifted
    assert dm.recording.t0.tolist() == [0.0] and dm.test_t0.tolist() == [0.0]
    dm.setup()
    assert torch.equal(dm.obs_y_test, y[444:554]) and torch.equal(dm.obs_t_test, dm.test_t)
    assert torch.bincount(dm.obs_traj_train).tolist() == [444]  # 2 samples: no window of 5
    pairs = RealPendulumData(dtype="float64", window=2)
    pairs.setup()
    assert torch.bincount(pairs.obs_traj_train).tolist() == [444, 2]
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


# ---------------------------------------------------------------- ids, times, dtypes


def test_ids_are_read_as_integers_exactly(tmp_path):
    big = 2**53  # 9007199254740992: float64 cannot tell it from 2**53 + 1
    csv = tmp_path / "ids.csv"
    csv.write_text(HEADER + f"{big},0,1,1\n{big + 1},0,2,2\n{big},1,1,1\n{big + 1},1,2,2\n")
    rec = load_recording(csv)
    assert rec.ids.tolist() == [big, big + 1] and rec.ids.dtype == torch.int64
    assert torch.bincount(rec.traj).tolist() == [2, 2] and rec.y[2:].eq(2).all()
    ids = np.array([big, big + 1, big, big + 1])
    for suffix in (".npz", ".pt"):
        path = tmp_path / f"ids{suffix}"
        arrays = {"trajectory": ids, "t": np.array([0.0, 0, 1, 1]), "y": np.ones((4, 2))}
        if suffix == ".npz":
            np.savez(path, **arrays)
        else:
            torch.save({k: torch.as_tensor(v) for k, v in arrays.items()}, path)
        assert load_recording(path).ids.tolist() == [big, big + 1]
    floats = tmp_path / "floats.csv"  # whole numbers in float notation: the same ids
    floats.write_text(HEADER + "3.0,0,1,1\n3e0,1,1,1\n-2.0,0,1,1\n-2,1,1,1\n")
    assert load_recording(floats).ids.tolist() == [-2, 3]
    exact = tmp_path / "exact.csv"  # read as decimals: 2⁵³ + 1 in float notation stays itself
    exact.write_text(
        HEADER + f"{big}.0,0,1,1\n{big}.0,1,1,1\n{big + 1}.0,0,1,1\n{big + 1}e0,1,1,1\n"
    )
    assert load_recording(exact).ids.tolist() == [big, big + 1]
    edge = tmp_path / "edge.csv"
    edge.write_text(
        HEADER + f"{2**63 - 1},0,1,1\n{2**63 - 1},1,1,1\n{-(2**63)},0,1,1\n-{2**63},1,1,1\n"
    )
    assert load_recording(edge).ids.tolist() == [-(2**63), 2**63 - 1]
    unsigned = tmp_path / "u.npz"
    np.savez(
        unsigned,
        trajectory=np.array([2**63 - 1] * 2, dtype=np.uint64),
        t=np.arange(2.0),
        y=np.ones((2, 2)),
    )
    assert load_recording(unsigned).ids.tolist() == [2**63 - 1]


def test_times_are_shifted_to_start_at_zero_before_any_cast(tmp_path):
    epoch = 1.7e9
    rows = [(m, epoch + 100 * m + 0.25 * j, [0.5 * j, 1.0]) for m in (4, 9) for j in range(5)]
    rec = load_recording(_write(tmp_path / "epoch.csv", rows), dtype="float32")
    assert rec.t0.tolist() == [epoch + 400, epoch + 900] and rec.t0.dtype == torch.float64
    assert rec.t.tolist() == [0.25 * j for j in range(5)] * 2  # exact: quarter steps
    ns = 1_700_000_000_123_456_789  # int64 nanoseconds: float64 would round to 256 ns
    path = tmp_path / "ns.npz"
    np.savez(path, trajectory=np.zeros(3, np.int64), t=ns + np.arange(3) * 100, y=np.ones((3, 2)))
    rec = load_recording(path)
    assert rec.t.tolist() == [0.0, 100.0, 200.0] and rec.t0.tolist() == [float(ns)]
    kept = load_recording(tmp_path / "epoch.csv", dtype="float64", shift=False)
    assert kept.t[0] == epoch + 400 and kept.t0.tolist() == [0.0, 0.0]
    with pytest.raises(
        ValueError, match=r"line 3: time 1700000400\.25 of trajectory 4 is 0\.25 after"
    ):
        load_recording(tmp_path / "epoch.csv", dtype="float32", shift=False)


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        (
            "0,0,1,1\n0,1000,1,1\n0,1000.0001,1,1\n",
            "line 4: time 1000.0001 of trajectory 0 is 0.0001 after its previous sample, 1000 "
            "after the trajectory's first; float32, the dtype times are served in, cannot "
            "resolve that step there (makes it 0.000122): set data.init_args.dtype: float64",
        ),
        (  # 1 % off: 4e-3 steps at 1e4, where float32's spacing is 9.8e-4
            "0,0,1,1\n0,10000,1,1\n0,10000.004,1,1\n",
            "line 4: time 10000.004 of trajectory 0 is 0.004 after",
        ),
        (
            "0,0,1,1\n0,1,1e39,1\n",
            "line 3: q1 = 1e+39 is beyond float32 (largest 3.403e+38), the dtype it is served in:"
            " set data.init_args.dtype: float64",
        ),
        ("0,0,1,1\n0,1,1,-4e38\n", "line 3: p1 = -4e+38 is beyond float32"),
        ("0,-1e39,1,1\n0,1e39,1,1\n", "line 3: time since its trajectory's start 2e+39 is beyond"),
    ],
)
def test_values_are_checked_in_the_dtype_they_are_served_in(tmp_path, body, expected):
    path = tmp_path / "r.csv"
    path.write_text(HEADER + body)
    with pytest.raises(ValueError) as info:
        load_recording(path, dtype="float32")
    assert str(info.value) == f"recording {path}, {expected}" or expected in str(info.value)
    assert str(info.value).startswith(f"recording {path}, line")
    assert "learning rate" not in str(info.value)
    exact = load_recording(path, dtype="float64")  # float64 serves it: read, float64 exact
    assert torch.isfinite(exact.y).all() and (exact.t[1:] > exact.t[:-1]).all()
    with pytest.raises(ValueError, match="set data.init_args.dtype: float64"):
        RecordingData(str(path), test_fraction=0.5)  # float32 by default: refused when built


def test_a_value_that_overflows_only_in_the_differences_is_refused_at_setup(tmp_path):
    rows = [(m, 1e-9 * j, [1e30 * (1 + 2 * j), 0.0]) for m in range(2) for j in range(3)]
    path = _write(tmp_path / "steep.csv", rows)
    dm = RecordingData(str(path), test_fraction=0.5)  # states and times fit float32
    with pytest.raises(ValueError) as info:
        dm.setup()
    assert str(info.value) == (
        "RecordingData: dx_train holds 2e+39, beyond float32 (largest 3.403e+38), the dtype it "
        "is served in: set data.init_args.dtype: float64"
    )
    wide = RecordingData(str(path), test_fraction=0.5, dtype="float64")
    wide.setup()
    assert float(wide.dx_train[0, 0]) == pytest.approx(2e39)


def test_the_fast_reader_and_the_line_reader_agree_and_name_lines(tmp_path):
    from hnn_pl.data.recording import _read_csv_fast, _read_csv_strict

    rows = _recorded_springs()
    plain = _write(tmp_path / "plain.csv", rows)
    text = plain.read_text().splitlines()
    noted = tmp_path / "noted.csv"  # comments and blank lines anywhere, \r\n line ends
    lines = ["# made by hand", "", *text[:5], "  # note", " \t", "", *text[5:]]
    noted.write_bytes("\r\n".join(lines).encode())
    marked = tmp_path / "marked.csv"  # a byte order mark, as spreadsheets write
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    for path in (plain, noted, marked):
        fast, strict = _read_csv_fast(path), _read_csv_strict(path)
        assert np.array_equal(fast[0], strict[0]) and np.array_equal(fast[1], strict[1])
        assert [fast[2](i) for i in range(36)] == [strict[2](i) for i in range(36)]
    where = _read_csv_strict(noted)[2]
    assert where(3) == "line 7" and where(4) == "line 11"  # after the 3 skipped lines
    a, b = load_recording(plain), load_recording(noted)
    for key in ("traj", "t", "y", "ids", "t0"):
        assert torch.equal(getattr(a, key), getattr(b, key)), key
    floats = tmp_path / "floats.csv"  # float-notation ids: the line reader alone
    floats.write_text(HEADER + "1.0,0,1,1\n1.0,1,1,1\n")
    assert _read_csv_fast(floats) is None and _read_csv_strict(floats)[0].tolist() == [1, 1]
    for path, sample in ((plain, 20), (noted, 3), (noted, 20)):
        lines = path.read_text().splitlines()
        n = int(_read_csv_strict(path)[2](sample).removeprefix("line "))
        cells = lines[n - 1].split(",")
        lines[n - 1] = ",".join([cells[0], cells[1], "inf", cells[3]])
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(ValueError, match=f"{path.name}, line {n}: non-finite value"):
            load_recording(path)
        lines[n - 1] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------- windows


def test_a_trajectory_shorter_than_the_window_is_refused_naming_it(tmp_path):
    path = _write(tmp_path / "s.csv", _recorded_springs(ids=(7, 2, 5), lengths=(12, 9, 15)))
    with pytest.raises(ValueError) as info:
        RecordingData(str(path), test_fraction=0.34, window=10)
    assert str(info.value) == (
        f"recording {path}: trajectory 2 has 9 samples, fewer than window 10, so it would "
        "give no windows: set data.init_args.window: 9"
    )
    with pytest.raises(ValueError) as info:
        RecordingData(str(path), test_fraction=0.34, window=6, keep_fraction=0.5)
    assert str(info.value) == (
        f"recording {path}: trajectory 2 keeps 5 of its 9 samples (keep_fraction 0.5), fewer "
        "than window 6, so it would give no windows: set data.init_args.window: 5"
    )
    dm = RecordingData(str(path), test_fraction=0.34, window=9)  # the fix: every one counts
    dm.setup()
    assert len(dm.windows_train) == (9 - 8) + (15 - 8) and len(dm.windows_test) == 12 - 8


def test_a_single_recording_leaves_out_pieces_too_short_for_a_window(tmp_path):
    path = _write(tmp_path / "one.csv", _recorded_springs(ids=(0,), lengths=(40,)))
    rec = load_recording(path)
    t = (rec.t + rec.t0[0]).tolist()
    dm = RecordingData(str(path), test_segment=(t[30], t[37]), window=5)  # 8 held out
    dm.setup()
    assert torch.bincount(dm.obs_traj_train).tolist() == [30]  # the 2 after it: no window
    assert len(dm.windows_train) == 26 and len(dm.windows_test) == 4
    both = RecordingData(str(path), test_segment=(t[30], t[37]), window=2)
    both.setup()
    assert torch.bincount(both.obs_traj_train).tolist() == [30, 2]
    with pytest.raises(ValueError, match="the held-out segment has 8 samples, fewer than window"):
        RecordingData(str(path), test_segment=(t[30], t[37]), window=9)
    with pytest.raises(ValueError, match="no piece outside the held-out segment keeps window 5"):
        RecordingData(str(path), test_segment=(t[2], t[37]), window=5)


# ------------------------------------------------------------ training and outputs


class StepLosses(Callback):
    """The training loss of every step (``train/loss``)."""

    def __init__(self) -> None:
        self.losses: list[float] = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self.losses.append(float(trainer.callback_metrics["train/loss"]))


def _trajectory_fit(tmp_path, name: str, offset: float, steps: int = 30) -> list[float]:
    """The step losses of the spring trajectory recipe (learned states, windows of 5) on
    four recorded springs whose times are shifted by ``offset``."""
    rows = _recorded_springs(ids=(3, 1, 4, 2), lengths=(30, 25, 28, 30), offset=offset)
    path = _write(tmp_path / f"{name}.csv", rows)
    config = tmp_path / f"{name}.yaml"
    config.write_text(
        "data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n"
        f"    path: {path}\n    test_fraction: 0.25\n    window: 5\n    batch_size: null\n"
    )
    args = ["--config=spring_traj.yaml", f"--config={config}", f"--trainer.max_steps={steps}"]
    cli = cli_main([*args, *quiet_args()], run=False, save_config=False)
    losses = StepLosses()
    cli.trainer.callbacks.append(losses)
    cli.trainer.fit(cli.model, cli.datamodule)
    assert cli.datamodule.obs_t_train.dtype == torch.float32
    return losses.losses


def test_epoch_times_train_to_the_losses_of_times_from_zero(tmp_path):
    """Unix-epoch times (+1.7e9 s, where float32 steps by 128 s) are served as times since
    each trajectory's start: the same losses as the recording starting near 0."""
    near_zero = _trajectory_fit(tmp_path, "zero", 0.0)
    epoch = _trajectory_fit(tmp_path, "epoch", 1.7e9)
    assert len(near_zero) == len(epoch) == 30
    assert near_zero[-1] < 0.5 * near_zero[0]  # it trains
    for a, b in zip(near_zero, epoch, strict=True):
        assert math.isclose(a, b, rel_tol=5e-4), (a, b)  # the same to 3 significant digits


def test_predict_gives_back_the_time_offsets(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rows = _recorded_springs(ids=(7, 2, 5, 9), lengths=(12, 9, 15, 11), offset=1.7e9)
    path = _write(tmp_path / "s.csv", rows)
    config = tmp_path / "recording.yaml"
    config.write_text(
        "data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n"
        f"    path: {path}\n    test_trajectories: [7, 2]\n    system: null\n"
        "trainer:\n  callbacks:\n    - class_path: hnn_pl.callbacks.RolloutWriter\n"
        "      init_args: {overrides: {t_end: null, n_points: null}}\n"
    )
    args = ["--config=spring_fast.yaml", f"--config={config}", "--trainer.max_steps=2"]
    args += ["--trainer.logger=false", "--trainer.enable_checkpointing=false"]
    cli = cli_main([*args, "--trainer.enable_progress_bar=false"], run=False, save_config=False)
    cli.trainer.fit(cli.model, cli.datamodule)
    cli.trainer.predict(cli.model, cli.datamodule)
    out = torch.load(tmp_path / "rollouts.pt", weights_only=True)
    assert out["t0"].dtype == torch.float64 and out["y_true"].shape[1] == 2
    for b, i in enumerate((2, 7)):  # held-out columns in id order
        file_t = torch.tensor([r[1] for r in rows if r[0] == i], dtype=torch.float64)
        seen = ~out["y_true"][:, b].isnan().any(-1)
        assert out["t0"][b] == file_t[0] and out["t"][0] == 0
        torch.testing.assert_close(
            out["t"][seen].double() + out["t0"][b], file_t, rtol=0, atol=1e-5
        )
    single = tmp_path / "one.csv"
    _write(single, _recorded_springs(ids=(4,), lengths=(30,), offset=1.7e9))
    rec = load_recording(single)
    t = (rec.t + rec.t0[0]).tolist()
    dm = RecordingData(str(single), test_segment=(t[20], t[29]), dtype="float64")
    dm.setup()
    assert dm.test_t0.tolist() == [rec.t0[0].item()]  # one trajectory keeps its own times
    torch.testing.assert_close(
        dm.test_t + dm.test_t0[0], torch.tensor(t[20:], dtype=torch.float64), rtol=0, atol=1e-6
    )


def _recording_config(tmp_path, model: str = "") -> Path:
    """A config as a user writes it: a windowed recording, a rollout callback with no
    task, and ``model`` (YAML) or the bundled config's model."""
    path = _write(tmp_path / "s.csv", _recorded_springs())
    config = tmp_path / "recording.yaml"
    config.write_text(
        "data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n"
        f"    path: {path}\n    test_fraction: 0.34\n    window: 3\n"
        "    system: {class_path: hnn_pl.systems.MassSpring}\n"
        "trainer:\n  callbacks:\n    - class_path: hnn_pl.callbacks.RolloutCallback\n"
        "      init_args: {every_n_epochs: 0}\n" + model
    )
    return config


def test_a_windowed_recording_trains_the_trajectory_objective_as_written(tmp_path, monkeypatch):
    """No ``objective`` given: the windows make it the trajectory objective (one switch);
    the rollout callback, given no task, rolls out the recording's held-out
    trajectories as recorded (there is no truth off them)."""
    from hnn_pl.evaluation import data_protocol

    monkeypatch.chdir(tmp_path)
    args = ["--config=spring_fast.yaml", f"--config={_recording_config(tmp_path)}"]
    args += [
        "--trainer.max_steps=2",
        "--trainer.logger=false",
        "--trainer.enable_progress_bar=false",
    ]
    cli = cli_main([*args, "--trainer.enable_checkpointing=false"], run=False, save_config=False)
    cli.trainer.fit(cli.model, cli.datamodule)
    assert cli.model.objective == cli.model.hparams.objective == "trajectory"
    (callback,) = [c for c in cli.trainer.callbacks if isinstance(c, RolloutCallback)]
    assert callback.protocol == PROTOCOL == data_protocol(cli.datamodule)
    (logged,) = cli.trainer.test(cli.model, cli.datamodule, verbose=False)
    assert math.isfinite(logged["rollout/state_mse"]) and math.isfinite(
        logged["rollout/energy_mse"]
    )


def test_a_windowed_recording_with_the_derivative_objective_is_refused_before_any_file(
    tmp_path, monkeypatch, capsys
):
    from hnn_pl.commands.main import main

    monkeypatch.chdir(tmp_path)
    config = _recording_config(tmp_path, "model:\n  init_args: {objective: derivative}\n")
    with pytest.raises(SystemExit) as info:
        main(["fit", "--config=spring_fast.yaml", f"--config={config}"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "python -m hnn_pl: error: data.init_args.window: 3 serves windows, which only the "
        "trajectory objective uses: set model.init_args.objective: trajectory, or window: null"
    ]
    assert not (tmp_path / "lightning_logs").exists()


def test_the_data_names_its_task_protocol(tmp_path):
    from hnn_pl.data import SimulatedData
    from hnn_pl.evaluation import data_protocol, task_protocol
    from hnn_pl.systems import Pendulum

    recorded = RecordingData(str(_write(tmp_path / "s.csv", _recorded_springs())))
    assert data_protocol(recorded) == PROTOCOL
    assert data_protocol(SimulatedData(system=Pendulum())) == task_protocol("pendulum")
    assert data_protocol(RealPendulumData()) == task_protocol("real_pendulum")
    with pytest.raises(ValueError, match="holds no task's data: only the clean protocol"):
        data_protocol(recorded, "reference")
