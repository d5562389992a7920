"""Numerical stress tests of :mod:`hnn_pl.integrate`: singular orbits, NaNs, scales."""

from __future__ import annotations

import math

import pytest
import torch

from hnn_pl import evaluation
from hnn_pl.integrate import Status, odeint
from hnn_pl.systems.mass_spring import MassSpring
from hnn_pl.systems.pendulum import Pendulum

F32, F64 = torch.float32, torch.float64
ECC = 0.9


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Rollouts of small batches are overhead-bound: with 2 intra-op threads on a busy
    2-core machine every op that enters a parallel region waits for a time slice."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def kepler(t, y):
    """One body around a fixed centre, ``H = |p|²/2 - 1/|q|``: ``(q̇, ṗ) = (p, -q/|q|³)``."""
    q, p = y[..., :2], y[..., 2:]
    r3 = q.square().sum(-1, keepdim=True) ** 1.5
    return torch.cat([p, -q / r3], -1)


def _energy(y):
    return 0.5 * y[..., 2:].square().sum(-1) - 1 / y[..., :2].norm(dim=-1)


def _angular_momentum(y):
    return y[..., 0] * y[..., 3] - y[..., 1] * y[..., 2]


@pytest.mark.parametrize(
    ("dtype", "rtol", "tol_e", "tol_l", "tol_r"),
    [(F64, 1e-10, 5e-8, 1e-8, 1e-8), (F32, 1e-6, 2e-3, 2e-4, 1e-5)],
    ids=["f64", "f32"],
)
def test_kepler_orbit_through_pericentre(dtype, rtol, tol_e, tol_l, tol_r):
    """Semi-major axis 1, eccentricity 0.9, from apocentre ``r = 1.9`` over two periods;
    the pericentre ``r = 0.1`` is passed at ``t = π`` with speed ``√19 ≈ 4.36``."""
    v_apo = math.sqrt((1 - ECC) / (1 + ECC))
    y0 = torch.tensor([[1 + ECC, 0.0, 0.0, v_apo]], dtype=dtype)
    t = torch.linspace(0, 4 * math.pi, 401, dtype=dtype)
    out = odeint(kepler, y0, t, method="dopri5", rtol=rtol, atol=rtol).double()
    assert torch.isfinite(out).all()
    e, ang = _energy(out), _angular_momentum(out)
    assert (e - (-0.5)).abs().max() / 0.5 < tol_e
    assert ((ang - ang[0]).abs().max() / ang[0].abs()).item() < tol_l
    r = out[..., :2].norm(dim=-1)
    assert abs(r[100].item() - (1 - ECC)) < tol_r, "pericentre at t = π"
    assert (out[-1] - out[0]).abs().max() < 1e3 * tol_e, "back at apocentre after two periods"


def _nan_beyond_two(t, y):
    """The pendulum field, NaN once ``|q| > 2`` (a rotating trajectory gets there)."""
    f = Pendulum().vector_field(t, y)
    return torch.where(y[..., :1].abs() > 2, torch.nan, f)


@pytest.mark.parametrize(
    "field",
    [lambda t, y: torch.sqrt(y - 10), _nan_beyond_two],
    ids=["always-nan", "nan-mid-trajectory"],
)
@pytest.mark.parametrize(
    ("method", "kwargs"),
    [("dopri5", {}), ("implicit_midpoint", {"step_size": 0.01})],
)
def test_nan_field_raises(field, method, kwargs):
    y0 = torch.tensor([[0.1, 0.0], [0.0, 3.0]], dtype=F64)
    t = torch.linspace(0, 5, 11, dtype=F64)
    with pytest.raises(RuntimeError, match="non-finite"):
        odeint(field, y0, t, method=method, **kwargs)


def test_dopri5_finite_time_blowup_raises():
    """``y' = y²`` from ``y = 1`` blows up at ``t = 1``."""
    y0 = torch.ones(2, 1, dtype=F64)
    with pytest.raises(RuntimeError, match="dopri5"):
        odeint(lambda t, y: y * y, y0, torch.tensor([0.0, 2.0], dtype=F64))


def test_dopri5_max_steps_raises():
    y0 = torch.tensor([[1.0, 0.0]], dtype=F64)
    t = torch.tensor([0.0, 100.0], dtype=F64)
    with pytest.raises(RuntimeError, match="max_steps"):
        odeint(MassSpring().vector_field, y0, t, rtol=1e-10, options={"max_steps": 50})


def test_implicit_midpoint_too_large_step_raises():
    """``y' = -A y`` with eigenvalues up to 1000: the iteration diverges for ``h = 0.1``."""
    a = torch.diag(torch.tensor([1.0, 10.0, 100.0, 1000.0], dtype=F64))

    def stiff(t, y):
        return -y @ a

    y0 = torch.ones(3, 4, dtype=F64)
    t = torch.tensor([0.0, 1.0], dtype=F64)
    with pytest.raises(RuntimeError, match="smaller step"):
        odeint(stiff, y0, t, method="implicit_midpoint", step_size=0.1)
    t = torch.tensor([0.0, 0.1], dtype=F64)
    out = odeint(stiff, y0, t, method="implicit_midpoint", step_size=1e-4)
    exact = torch.exp(-0.1 * torch.diag(a))
    assert (out[-1] - exact).abs().max() < 1e-4


@pytest.mark.parametrize("atol_per_scale", [False, True], ids=["atol=0", "atol~scale"])
def test_dopri5_relative_accuracy_across_scales(atol_per_scale):
    """Springs of amplitude 1e-6, 1 and 1e6 in one batch keep a relative error ~rtol."""
    spring = MassSpring()
    scale = torch.tensor([1e-6, 1.0, 1e6], dtype=F64)[:, None]
    y0 = torch.tensor([[0.6, -0.8]], dtype=F64) * scale
    t = torch.linspace(0, 5, 26, dtype=F64)
    out = odeint(spring.vector_field, y0, t, rtol=1e-10, atol=0.0)
    if atol_per_scale:
        out = torch.cat(
            [
                odeint(spring.vector_field, y0[i : i + 1], t, rtol=1e-10, atol=1e-10 * s.item())
                for i, s in enumerate(scale)
            ],
            dim=1,
        )
    rel = (out - spring.exact_solution(t, y0)).abs().amax((0, 2)) / scale[:, 0]
    assert (rel < 1e-8).all(), f"relative errors {rel.tolist()}"


def test_rk4_batch_of_1000_pendulums_float32_stays_finite():
    pend = Pendulum()
    y0 = pend.sample_initial(1000, torch.Generator().manual_seed(0)).float()
    t = torch.linspace(0, 50, 11)
    out = odeint(pend.vector_field, y0, t, method="rk4", step_size=0.05)
    assert out.dtype == F32 and torch.isfinite(out).all()
    drift = (pend.hamiltonian(out[-1]) - pend.hamiltonian(y0)).abs().max()
    assert drift < 1e-2, f"energy drift {drift:.3e}"


def _cliff(t, y):
    """A pendulum, ``(q̇, ṗ) = (p, -sin q)``, with a cliff beyond ``q = 4`` where
    ``ṗ`` gains ``1e3 (q - 4)³``: a start past the cliff blows up in finite time,
    starts with ``|q| < π`` never reach it. Rows are independent."""
    q, p = y[..., :1], y[..., 1:]
    return torch.cat([p, -torch.sin(q) + 1e3 * torch.relu(q - 4) ** 3], -1)


CLEAN = torch.tensor([[0.5, 0.0], [-1.0, 0.3], [2.0, -0.5]], dtype=F64)
CLIFF = torch.tensor([[4.5, 1.0]], dtype=F64)


@pytest.mark.parametrize(
    ("method", "kwargs"),
    [
        ("rk4", {"step_size": 0.01}),
        ("leapfrog", {"step_size": 0.01}),
        ("implicit_midpoint", {"step_size": 0.01}),
        ("dopri5", {"rtol": 1e-9, "atol": 1e-9}),
    ],
)
def test_a_diverging_row_stops_alone(method, kwargs):
    """The blown-up row stops with its time; the others equal a run without it (dopri5:
    to the rounding of batched kernels, as a row alone and in a batch differ, ≈1e-15)."""
    t = torch.linspace(0, 3, 31, dtype=F64)
    clean = odeint(_cliff, CLEAN, t, method=method, **kwargs)
    sol = odeint(
        _cliff, torch.cat([CLEAN[:2], CLIFF, CLEAN[2:]]), t, method, return_status=True, **kwargs
    )
    tol = 1e-13 if method == "dopri5" else 0.0
    torch.testing.assert_close(sol.y[:, [0, 1, 3]], clean, rtol=0, atol=tol)
    assert sol.status.tolist()[:2] == [Status.OK, Status.OK] and sol.status[3] == Status.OK
    assert sol.status[2] != Status.OK and 0 < float(sol.t_stop[2]) < 3.0
    stop = int(torch.searchsorted(t, sol.t_stop[2]))
    assert torch.isnan(sol.y[stop + 1 :, 2]).all() and torch.isfinite(sol.y[:stop, 2]).all()
    with pytest.raises(RuntimeError, match=r"1 of 4 rows stopped .* rows \[2\]"):
        odeint(_cliff, torch.cat([CLEAN[:2], CLIFF, CLEAN[2:]]), t, method, **kwargs)


def test_rk4_reports_the_time_of_divergence_backward_too():
    t = torch.linspace(0, -3, 31, dtype=F64)
    sol = odeint(_cliff, torch.tensor([[4.5, -1.0]], dtype=F64), t, "rk4", return_status=True)
    assert sol.status[0] == Status.DIVERGED and -3.0 < float(sol.t_stop[0]) < 0


def test_dopri5_collision_stops_that_row_and_finishes_the_others():
    """Zero angular momentum: the body falls into the centre at t = π/(2√2)."""
    y0 = torch.tensor([[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 1.0]], dtype=F64)
    t = torch.linspace(0, 5, 11, dtype=F64)
    sol = odeint(kepler, y0, t, rtol=1e-10, atol=1e-10, return_status=True)
    assert sol.status[0] in (Status.STEP_UNDERFLOW, Status.DIVERGED)
    assert float(sol.t_stop[0]) == pytest.approx(math.pi / 2**1.5, abs=1e-3)
    assert sol.status[1] == Status.OK and torch.isfinite(sol.y[:, 1]).all()


def test_dopri5_stops_a_stiff_row_early():
    """Van der Pol, μ = 1000: explicit steps are bounded by stability, not accuracy."""

    def vdp(t, y):
        x, v = y[..., :1], y[..., 1:]
        return torch.cat([v, 1000 * (1 - x**2) * v - x], -1)

    t = torch.tensor([0.0, 3000.0], dtype=F64)
    sol = odeint(vdp, torch.tensor([[2.0, 0.0]], dtype=F64), t, return_status=True)
    assert sol.status[0] == Status.STIFF and float(sol.t_stop[0]) < 30
    with pytest.raises(RuntimeError, match="stiff"):
        odeint(vdp, torch.tensor([[2.0, 0.0]], dtype=F64), t)


def test_unreachable_tolerance_fails_before_any_step():
    y0 = torch.tensor([[1.0, 0.0]], dtype=F32)
    t = torch.tensor([0.0, 20.0], dtype=F32)
    with pytest.raises(ValueError, match="resolution"):
        odeint(MassSpring().vector_field, y0, t, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("method", ["euler", "rk4", "leapfrog", "implicit_midpoint", "dopri5"])
def test_a_field_of_the_wrong_shape_is_refused(method):
    y0 = torch.tensor([[1.0, 0.0]], dtype=F64)
    with pytest.raises(ValueError, match=r"shape \(1, 1\) for states of shape \(1, 2\)"):
        odeint(lambda t, y: y[:, :1], y0, torch.tensor([0.0, 1.0], dtype=F64), method)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"t": [0.0, math.inf]}, "t must be finite"),
        ({"rtol": math.nan}, "rtol must be finite"),
        ({"atol": -1.0}, "atol must be finite"),
        ({"method": "rk4", "step_size": math.nan}, "step_size"),
    ],
)
def test_bad_times_and_tolerances_are_refused(kwargs, match):
    args = {"t": [0.0, 1.0], "method": "dopri5", **kwargs}
    t = torch.tensor(args.pop("t"), dtype=F64)
    with pytest.raises(ValueError, match=match):
        odeint(MassSpring().vector_field, torch.ones(1, 2, dtype=F64), t, **args)


class _CliffField(torch.nn.Module):
    """A module whose ``vector_field`` is :func:`_cliff` (no parameters)."""

    def vector_field(self, t, y):
        return _cliff(t, y)


def test_rollout_scores_the_finite_rows_and_counts_the_others():

    y0 = torch.cat([CLEAN, CLIFF])
    t = torch.linspace(0, 3, 31, dtype=F64)
    out = evaluation.rollout(_CliffField(), y0, t, "rk4", step_size=0.01)
    assert (
        out.status.tolist() == [0, 0, 0, Status.DIVERGED] and torch.isnan(out.y_pred[-1, 3]).all()
    )
    y_true = odeint(_cliff, CLEAN, t, "rk4", step_size=0.01)
    truth = torch.cat([y_true, torch.zeros(31, 1, 2, dtype=F64)], 1)
    energy = Pendulum().energy
    r = evaluation.Rollout(
        t, truth, out.y_pred, energy(truth), energy(out.y_pred), status=out.status
    )
    metrics = evaluation.score(r)
    assert metrics["diverged_rows"] == 1 and metrics["energy_mse"] == 0.0
    assert metrics["state_mse"] == 0.0
