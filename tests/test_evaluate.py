"""Evaluation protocols: a perfect model scores ~0, quirks do what they say."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from hnn_pl import evaluation
from hnn_pl.data import RealPendulumData, SimulatedData
from hnn_pl.evaluation import ReferenceProtocol, grouped_mean
from hnn_pl.evaluation.reference import _box_starts, _scipy_rollout
from hnn_pl.systems import MassSpring, Pendulum


def evaluate_protocol(model, dm, protocol) -> dict:
    """The protocol's metrics with how many trajectories and how long (as reports give)."""
    metrics, r = evaluation.evaluate(model, dm, protocol)
    return {**metrics, **evaluation.report(r)}


def evaluate_reference(model, dm, task, protocol=None) -> dict:
    return evaluate_protocol(model, dm, protocol or evaluation.task_protocol(task, "reference"))


class TrueField(nn.Module):
    """A 'model' whose field is the system's own (optionally damped)."""

    def __init__(self, system, damping: float = 0.0) -> None:
        super().__init__()
        self.system, self.damping = system, damping

    def vector_field(self, t, y):
        f = self.system.vector_field(t, y)
        return f - self.damping * torch.cat([torch.zeros_like(y[..., :1]), y[..., 1:]], -1)


@pytest.fixture(scope="module")
def spring_dm(tmp_path_factory):
    dm = SimulatedData(MassSpring(), cache_dir=str(tmp_path_factory.mktemp("c")), dtype="float64")
    dm.setup()
    return dm


@pytest.mark.parametrize("task", ["spring", "pendulum"])
def test_reference_protocol_scores_the_true_field_near_zero(task, spring_dm, tmp_path):
    dm = (
        spring_dm
        if task == "spring"
        else SimulatedData(Pendulum(), n_points=45, cache_dir=str(tmp_path))
    )
    dm.setup()
    good = evaluate_reference(TrueField(dm.system), dm, task)
    bad = evaluate_reference(TrueField(dm.system, damping=0.05), dm, task)
    # scipy's default atol = 1e-6 (quirk 5) bounds the accuracy of both paths
    assert good["energy_mse"] < 1e-8
    assert bad["energy_mse"] > 1e3 * max(good["energy_mse"], 1e-12)
    assert good["n_trajectories"] == 15 and good["t_end"] == 20.0
    assert math.isfinite(bad["energy_mse_pm"]) and bad["energy_mse_pm"] > 0


def test_spring_time_stretch_compounds_per_trial():
    """Trial k (1…15) of the spring is read at 1.09**(k+1) · t: the reference's in-place
    bug, whose last horizon is t ≈ 79."""
    system = MassSpring()
    p = evaluation.task_protocol("spring", "reference")
    y0 = _box_starts(p, 2, seed=0)
    t = torch.linspace(0, 20, 100, dtype=torch.float64)
    stretch = p.time_stretch ** torch.arange(2, 17, dtype=torch.float64)
    tight = ReferenceProtocol(rtol=1e-10, atol=1e-10)
    y = _scipy_rollout(system.vector_field, y0, t, tight, stretch)
    for k in (0, 14):
        exact = system.exact_solution(stretch[k] * t, y0[k : k + 1])[:, 0]
        torch.testing.assert_close(y[:, k], exact, rtol=1e-6, atol=1e-7)
    assert evaluation.task_protocol("spring", "reference").compound_stretch
    assert 79 < 20 * float(stretch[-1]) < 80


def test_box_starts_cover_both_signs_of_the_range():
    y0 = _box_starts(ReferenceProtocol(n_starts=2000), 2, seed=0)
    mag = y0.abs()
    assert mag.min() >= 0.2 and mag.max() <= 1.0
    assert 0.4 < (y0 > 0).double().mean() < 0.6


def test_pendulum_reference_energy_is_q2_plus_p2(tmp_path):
    dm = SimulatedData(Pendulum(), n_points=45, cache_dir=str(tmp_path))
    dm.setup()
    p = evaluation.task_protocol("pendulum", "reference")
    assert p.energy == "q2p2" and p.time_stretch == 1.0
    default_energy = evaluate_reference(
        TrueField(dm.system, 0.05), dm, "pendulum", ReferenceProtocol(energy="system")
    )
    quirk = evaluate_reference(TrueField(dm.system, 0.05), dm, "pendulum")
    assert default_energy["energy_mse"] != pytest.approx(quirk["energy_mse"], rel=1e-3)


def test_clean_protocol_scores_the_true_field_near_zero(spring_dm):
    good = evaluate_protocol(
        TrueField(spring_dm.system), spring_dm, evaluation.task_protocol("spring", "clean")
    )
    bad = evaluate_protocol(
        TrueField(spring_dm.system, 0.05), spring_dm, evaluation.task_protocol("spring", "clean")
    )
    assert good["energy_mse"] < 1e-14 and good["state_mse"] < 1e-12
    assert bad["energy_mse"] > 1e-4
    assert good["n_trajectories"] == 25 and good["t_end"] == 20.0


def test_field_error_is_zero_for_the_true_field_and_the_damping_share_otherwise(spring_dm):
    """H = q² + p²: f = (2p, −2q); damping c on p adds (0, −c·p), so over the true
    states ‖f_θ − f‖² / ‖f‖² = c² Σp² / Σ 4(q² + p²)."""
    clean = evaluation.task_protocol("spring", "clean")
    good = evaluate_protocol(TrueField(spring_dm.system), spring_dm, clean)
    bad = evaluate_protocol(TrueField(spring_dm.system, 0.05), spring_dm, clean)
    _, y = spring_dm.rollout_target(clean.t_end, clean.n_points)
    expected = 0.05 * float((y[..., 1] ** 2).sum().sqrt() / (4 * (y**2).sum()).sqrt())
    assert good["field_error"] < 1e-12
    assert bad["field_error"] == pytest.approx(expected, rel=1e-9)


def test_real_pendulum_field_error_reads_the_recordings_central_differences(tmp_path):
    """On the evenly spaced interior, ``true_field`` is (y[i+1] − y[i−1]) / 2Δt."""
    dm = RealPendulumData(cache_dir=str(tmp_path), dtype="float64")
    dm.setup()
    t, y = dm.rollout_target()
    f = dm.true_field(t, y)
    gaps = t[1:] - t[:-1]
    i = int(torch.nonzero((gaps[1:] - gaps[:-1]).abs() < 1e-9)[5]) + 1
    torch.testing.assert_close(f[i], (y[i + 1] - y[i - 1]) / float(t[i + 1] - t[i - 1]))
    clean = evaluate_protocol(
        TrueField(dm.system), dm, evaluation.task_protocol("real_pendulum", "clean")
    )
    assert 0 < clean["field_error"] < math.inf


def test_real_pendulum_protocols_use_the_measured_segment(tmp_path):
    dm = RealPendulumData(cache_dir=str(tmp_path), dtype="float64")
    dm.setup()
    ref = evaluate_reference(TrueField(dm.system), dm, "real_pendulum")
    clean = evaluate_protocol(
        TrueField(dm.system), dm, evaluation.task_protocol("real_pendulum", "clean")
    )
    assert ref["n_trajectories"] == clean["n_trajectories"] == 1
    assert ref["t_end"] == pytest.approx(99.1667, abs=1e-3)
    # the ideal pendulum is not the measured one (friction): a finite, non-zero error
    assert 1e-6 < clean["energy_mse"] < 1.0


def test_grouped_mean_is_std_of_group_means_over_root_groups():
    x = torch.arange(15.0)
    mean, pm = grouped_mean(x, 5)
    groups = torch.tensor([1.0, 4.0, 7.0, 10.0, 13.0])
    assert mean == pytest.approx(7.0)
    assert pm == pytest.approx(float(groups.std() / 5**0.5))
    assert math.isnan(grouped_mean(x[:1], 1)[1])


def test_error_floors_are_the_systems_computed_once_for_every_model(spring_dm, monkeypatch):
    """The floors depend on no model: a second model's rollout reuses the first's (the true
    system is not integrated again), a changed system or protocol computes them anew,
    and the kept floors equal a fresh computation."""
    from hnn_pl.evaluation import views

    p = evaluation.task_protocol("spring", "clean").replace(max_starts=3, t_end=2.0, n_points=21)
    monkeypatch.setattr(views, "_FLOORS", {})
    calls = []
    real = views._error_floors
    monkeypatch.setattr(views, "_error_floors", lambda *a: calls.append(a[1]) or real(*a))
    first = p.run(TrueField(spring_dm.system), spring_dm).floors
    second = p.run(TrueField(spring_dm.system, damping=0.1), spring_dm).floors
    assert len(calls) == 1 and first.keys() == second.keys() and first
    for name, value in first.items():
        assert torch.equal(value, second[name])
    t, y = spring_dm.rollout_target(p.t_end, p.n_points)
    fresh = real(spring_dm, spring_dm.system, t, y[:, :3], p)
    for name, value in fresh.items():
        torch.testing.assert_close(first[name], value, rtol=0, atol=0)
    p.replace(method="rk4", step_size=0.1).run(TrueField(spring_dm.system), spring_dm)
    monkeypatch.setattr(spring_dm, "system", MassSpring(alpha=2.0))
    p.run(TrueField(spring_dm.system), spring_dm)
    assert len(calls) == 3


def test_a_rollout_integrates_the_truth_of_its_scored_starts_only(tmp_path, monkeypatch):
    """A protocol over the first ``max_starts`` held-out starts integrates the truth from
    those alone (the three-body's protocol scores 100 of 1,000), and gives the rows a
    whole-set truth gives them, bit for bit (dopri5's error control is per row)."""
    from hnn_pl.evaluation.views import rollout_target
    from hnn_pl.systems import ThreeBody

    dm = SimulatedData(ThreeBody(), n_trajectories=12, n_points=5, cache_dir=str(tmp_path))
    dm.prepare_data()
    dm.setup("test")
    widths, real = [], dm.system.trajectory

    def counted(y0, t):
        widths.append(len(y0))
        return real(y0, t)

    monkeypatch.setattr(dm.system, "trajectory", counted)
    p = evaluation.Protocol(t_end=1.0, n_points=20, max_starts=2)
    t, y = rollout_target(dm, p)
    assert widths == [2] and y.shape == (20, 2, dm.state_dim) and len(t) == 20
    assert rollout_target(dm, p)[1].shape[1] == 2 and widths == [2]  # cached
    _, whole = dm.rollout_target(1.0, 20)
    assert widths == [2, 6] and whole.shape[1] == 6
    torch.testing.assert_close(y, whole[:, :2], rtol=0, atol=0)
    assert dm.rollout_target(1.0, 20, max_starts=4)[1].shape[1] == 4 and widths == [2, 6]
    assert dm.rollout_target(None, max_starts=3)[1].shape[1] == 3
