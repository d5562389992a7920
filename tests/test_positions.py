"""Positions only: data of what a camera or an encoder records, latent momenta, the
observer protocol's scores."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from hnn_pl.data import RecordingData, SimulatedData
from hnn_pl.data.differences import position_pairs, smoothed_velocity
from hnn_pl.data.recording import load_recording
from hnn_pl.models import HNN
from hnn_pl.models.base import with_momenta
from hnn_pl.systems import MassSpring, Pendulum

F64 = torch.float64


def test_smoothed_velocity_is_exact_for_quadratics_at_uneven_times():
    g = torch.Generator().manual_seed(0)
    t = torch.cat([torch.rand(12, generator=g, dtype=F64).sort().values * 3, torch.arange(4.0)])
    t = t.to(F64)
    traj = torch.tensor([0] * 12 + [1] * 4)
    q = torch.stack([1 + 2 * t - 0.7 * t**2, 3 * t - 0.1 * t**2], -1)
    exact = torch.stack([2 - 1.4 * t, 3 - 0.2 * t], -1)
    torch.testing.assert_close(smoothed_velocity(q, t, traj), exact, rtol=0, atol=1e-10)


def test_position_pairs_are_central_differences_of_positions_then_velocities():
    t = torch.linspace(0, 1, 11, dtype=F64)
    q = (t**2)[:, None]
    x, dx = position_pairs(q, t, torch.zeros(11, dtype=torch.long))
    torch.testing.assert_close(x[1:-1, 1], 2 * t[1:-1], rtol=0, atol=1e-12)  # v = 2t inside
    torch.testing.assert_close(dx[2:-2, 1], torch.full((7,), 2.0, dtype=F64), rtol=0, atol=1e-9)
    torch.testing.assert_close(dx[:, 0], x[:, 1])


def test_simulated_positions_are_the_states_draws_without_momenta(tmp_path):
    kw = dict(system=Pendulum(), n_trajectories=6, n_points=20, seed=3, cache_dir=str(tmp_path))
    states = SimulatedData(**kw, window=4)
    positions = SimulatedData(**kw, window=4, observe="positions")
    states.setup("fit"), positions.setup("fit")
    assert positions.obs_y_train.shape == (60, 1)
    torch.testing.assert_close(positions.obs_y_train, states.obs_y_train[:, :1])
    torch.testing.assert_close(positions.test_y, states.test_y)  # the truth keeps its momenta
    assert positions.state_dim == 2 and positions.x_train.shape == (60, 2)


@pytest.mark.parametrize("header", ["trajectory,time,q", "trajectory,time,q1"])
def test_a_positions_csv_round_trips(tmp_path, header):
    path = tmp_path / "camera.csv"
    rows = [(b, 0.1 * i + 5.0, math.sin(0.3 * i + b)) for b in range(3) for i in range(8)]
    path.write_text(header + "\n" + "".join(f"{b},{t!r},{q!r}\n" for b, t, q in rows))
    rec = load_recording(path)
    assert rec.positions and rec.state_dim == 2 and rec.y.shape == (24, 1)
    expected = torch.tensor([q for _, _, q in rows], dtype=F64)[:, None]
    torch.testing.assert_close(rec.y, expected, rtol=0, atol=0)
    torch.testing.assert_close(rec.t0, torch.full((3,), 5.0, dtype=F64))
    dm = RecordingData(path=str(path), system=Pendulum(), window=4)
    dm.setup("fit")
    assert dm.observe == "positions" and dm.hparams["observe"] == "positions"
    assert dm.state_dim == 2 and dm.obs_y_train.shape[-1] == 1 and not dm.has_energy


def test_a_positions_npz_with_q_reads_as_positions(tmp_path):
    path = tmp_path / "encoder.npz"
    q = np.stack([np.linspace(0, 1, 10), np.linspace(1, 0, 10)], -1)
    np.savez(path, trajectory=np.repeat([4, 9], 5), t=np.tile(np.arange(5.0), 2), q=q)
    rec = load_recording(path)
    assert rec.positions and rec.state_dim == 4
    torch.testing.assert_close(rec.y, torch.from_numpy(q))


def test_states_headers_q_p_and_q1_p1_read_alike(tmp_path):
    body = "0,0,1,2\n0,1,3,4\n"
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("trajectory,time,q,p\n" + body)
    b.write_text("trajectory,time,q1,p1\n" + body)
    ra, rb = load_recording(a), load_recording(b)
    assert not ra.positions and ra.state_dim == 2
    torch.testing.assert_close(ra.y, rb.y)


def test_latent_momenta_start_at_the_fitted_velocity():
    t = torch.linspace(0, 1, 9, dtype=F64)
    q = (3 * t + t**2)[:, None]
    states = with_momenta(q, t, torch.zeros(9, dtype=torch.long), 2)
    torch.testing.assert_close(states[:, 1], 3 + 2 * t, rtol=0, atol=1e-10)
    assert with_momenta(states, t, torch.zeros(9, dtype=torch.long), 2) is states


def _windows(dm):
    y, t, index = dm._windowed["train"]
    return y[:8], t[:8], index[:8]


def test_positions_windows_train_the_momenta_and_compare_positions_only(tmp_path):
    dm = SimulatedData(
        system=MassSpring(),
        n_trajectories=4,
        n_points=12,
        seed=0,
        dtype="float64",
        window=4,
        observe="positions",
        cache_dir=str(tmp_path),
    )
    dm.setup("fit")
    model = HNN(objective="trajectory", learned_states="sample", continuity_weight=1.0).double()
    model.init_states(dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train)
    assert model.states.shape == (len(dm.obs_y_train), 2)
    parts = model.window_loss(_windows(dm))
    parts["loss"].backward()
    assert model.states.grad[:, 1].abs().sum() > 0  # the momenta learn
    y, t, index = _windows(dm)
    pred = model.integrate_windows(model.states[index[:, 0]], t)
    fit = ((pred[:, 1:, :1] - y[:, 1:]) ** 2).mean()
    torch.testing.assert_close(parts["fit"], fit)


def test_positions_refuse_windows_without_learned_states(tmp_path):
    from lightning import Trainer

    dm = SimulatedData(
        system=MassSpring(),
        n_trajectories=4,
        n_points=12,
        seed=0,
        window=4,
        observe="positions",
        cache_dir=str(tmp_path),
    )
    model = HNN(objective="trajectory")
    trainer = Trainer(max_steps=1, logger=False, enable_checkpointing=False, barebones=True)
    with pytest.raises(ValueError, match="learned_states: sample"):
        trainer.fit(model, dm)


def test_the_campaign_scores_the_structured_twin_beside_the_recipe_and_like_for_like():
    """The spring's structured positions twin has its own rows; its criteria divide by
    the states recipe's HNN and, like for like, by the same model on the states recipe,
    and the recipe's own line is unchanged (synthetic records: position MSE 2 for the
    positions HNN, 1.5 for the twin, against 1 and 3)."""
    from hnn_pl.experiments.positions import MECHANICAL, ROWS, STRUCTURED, criteria, summarise

    assert STRUCTURED == ("spring",)
    spring = {(label, model): (config, extra) for label, model, config, extra in ROWS["spring"]}
    assert spring[("states", "mechanical_hnn")] == ("spring_traj.yaml", MECHANICAL)
    assert spring[("positions", "mechanical_hnn")][0] == "spring_positions_mechanical_hnn.yaml"
    assert spring[("positions", "hnn")] == ("spring_positions.yaml", ())
    assert ("positions, half the samples", "mechanical_hnn") in spring
    assert not any(model == "mechanical_hnn" for _, model, _, _ in ROWS["pendulum"])

    def run(row, model, mse):
        return {
            "task": "spring",
            "row": row,
            "model": model,
            "seed": 0,
            "position_mse": mse,
            "energy_mse": mse,
            "train_s": mse,
        }

    records = [
        run("positions", "hnn", 2.0),
        run("positions, half the samples", "hnn", 3.0),
        run("positions", "mechanical_hnn", 1.5),
        run("positions, half the samples", "mechanical_hnn", 6.0),
        run("states", "hnn", 1.0),
        run("states", "mechanical_hnn", 3.0),
        run("finite differences", "hnn", 8.0),
    ]
    lines = criteria(summarise(records))
    assert "positions / states: position MSE 2.00 (target ≤ 2)" in lines[2]
    assert "finite differences / positions: position MSE 4.0" in lines[2]
    assert "half the samples / all: 1.50" in lines[2]
    twin = lines[3]
    assert twin.startswith("- spring, the structured twin (mechanical_hnn)")
    assert "position MSE 1.50, energy 1.50, training 1.50" in twin
    assert "like for like (mechanical_hnn from states): position MSE 0.50" in twin
    assert twin.endswith("half the samples / all: 4.00")


def test_the_half_samples_rows_keep_the_windows_duration():
    """Half the samples: windows of half the config's samples, so that a window spans
    about the same time as on all of them."""
    from hnn_pl.commands.config_paths import config_chain, resolve_config
    from hnn_pl.experiments.positions import HALF, ROWS

    assert HALF[0] == "--data.init_args.keep_fraction=0.5"
    for task in ("spring", "pendulum"):
        halves = [(c, x) for label, _, c, x in ROWS[task] if label.endswith("half the samples")]
        assert halves
        for config, extra in halves:
            window = None
            for _, mapping in config_chain(resolve_config(config)):
                window = ((mapping.get("data") or {}).get("init_args") or {}).get("window", window)
            assert extra == HALF and HALF[1] == f"--data.init_args.window={window // 2}"


def test_the_real_pendulum_criteria_divide_the_angles_only_model_by_the_states_one():
    """The real pendulum's line: the angles-only dissipative model's slope against the
    recording's, its position MSE and its training time against the states-only
    dissipative model's (synthetic records: slope −0.009 of −0.012, position MSE 3 against
    2, training 50 s against 10 s)."""
    from hnn_pl.experiments.positions import criteria, summarise

    def run(row, mse, train_s):
        return {
            "task": "real_pendulum",
            "row": row,
            "model": "dissipative",
            "seed": 0,
            "position_mse": mse,
            "energy_mse": 0.1,
            "energy_drift_slope": -0.009,
            "true_energy_drift_slope": -0.012,
            "train_s": train_s,
        }

    (line,) = criteria(summarise([run("positions", 3.0, 50.0), run("states", 2.0, 10.0)]))[2:]
    assert "energy slope -0.009 per s, 0.75 of the recording's -0.012" in line
    assert "position MSE 1.50 of the states-only dissipative's (≤ 1.5)" in line
    assert line.endswith("training 5.00 (≤ 2)")
