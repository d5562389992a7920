"""Numerical stress tests of :mod:`hnn_pl.integrate`: singular orbits, NaNs, scales."""

from __future__ import annotations

import math

import pytest
import torch

from hnn_pl.integrate import odeint
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
