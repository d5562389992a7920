"""Accuracy, order, symplecticity and API of :mod:`hnn_pl.integrate`."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from hnn_pl.integrate import METHODS, odeint, scipy_fun, scipy_odeint
from hnn_pl.systems.mass_spring import MassSpring
from hnn_pl.systems.pendulum import Pendulum

F32, F64 = torch.float32, torch.float64
FIXED = ["euler", "rk4", "leapfrog", "implicit_midpoint"]
ALL = [*FIXED, "dopri5"]


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Rollouts of small batches are overhead-bound: with 2 intra-op threads on a busy
    2-core machine every op that enters a parallel region waits for a time slice."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# method -> (odeint kwargs per dtype, max |error| per dtype) on the spring, t in [0, 3]
SPRING = {
    "euler": ({F32: {"step_size": 1e-3}, F64: {"step_size": 1e-3}}, {F32: 1e-2, F64: 1e-2}),
    "rk4": ({F32: {"step_size": 1e-2}, F64: {"step_size": 1e-2}}, {F32: 5e-6, F64: 5e-8}),
    "leapfrog": ({F32: {"step_size": 1e-2}, F64: {"step_size": 1e-2}}, {F32: 3e-4, F64: 3e-4}),
    "implicit_midpoint": (
        {F32: {"step_size": 1e-2}, F64: {"step_size": 1e-2, "rtol": 1e-12, "atol": 1e-12}},
        {F32: 5e-4, F64: 5e-4},
    ),
    "dopri5": (
        {F32: {"rtol": 1e-6, "atol": 1e-6}, F64: {"rtol": 1e-10, "atol": 1e-10}},
        {F32: 3e-5, F64: 3e-9},
    ),
}


def _spring_states(n: int = 16, seed: int = 0) -> torch.Tensor:
    return MassSpring().sample_initial(n, torch.Generator().manual_seed(seed))


def _dop853(func, y0: torch.Tensor, t: torch.Tensor, tol: float = 1e-12) -> torch.Tensor:
    """Reference ``(T, B, D)`` float64 from scipy's DOP853 on the flattened batch."""
    return scipy_odeint(func, y0, t, "DOP853", rtol=tol, atol=tol)


class Counter:
    """Wraps a field and counts calls and evaluated rows."""

    def __init__(self, func):
        self.func, self.calls, self.rows = func, 0, 0

    def __call__(self, t, y):
        self.calls += 1
        self.rows += y.shape[0]
        return self.func(t, y)


@pytest.mark.parametrize("dtype", [F32, F64], ids=["f32", "f64"])
@pytest.mark.parametrize("method", ALL)
def test_spring_matches_analytic(method, dtype):
    spring = MassSpring()
    y0 = _spring_states()
    t = torch.linspace(0, 3, 31, dtype=F64)
    kwargs, tol = SPRING[method][0][dtype], SPRING[method][1][dtype]
    out = odeint(spring.vector_field, y0.to(dtype), t.to(dtype), method=method, **kwargs)
    assert out.shape == (31, 16, 2) and out.dtype == dtype
    assert torch.equal(out[0], y0.to(dtype))
    err = (out.double() - spring.exact_solution(t, y0)).abs().max().item()
    assert err < tol, f"{method} {dtype}: max error {err:.3e} >= {tol:.0e}"


@pytest.mark.parametrize(
    ("dtype", "rtol", "tol"), [(F64, 1e-10, 1e-7), (F32, 1e-6, 1e-3)], ids=["f64", "f32"]
)
def test_dopri5_matches_dop853_on_pendulum(dtype, rtol, tol):
    pend = Pendulum()
    y0 = pend.sample_initial(8, torch.Generator().manual_seed(1)).to(dtype)
    t = torch.linspace(0, 10, 51, dtype=dtype)
    ref = _dop853(pend.vector_field, y0, t)
    field = Counter(pend.vector_field)
    out = odeint(field, y0, t, method="dopri5", rtol=rtol, atol=rtol)
    err = (out.double() - ref).abs().max().item()
    assert err < tol, f"max |dopri5 - DOP853| = {err:.3e}"
    assert field.rows < 8 * 6 * 2000


@pytest.mark.parametrize(
    ("method", "steps"),
    [
        ("euler", [2e-3, 1e-3, 5e-4, 2.5e-4]),
        ("rk4", [0.1, 0.05, 0.025, 0.0125]),
        ("leapfrog", [0.04, 0.02, 0.01, 0.005]),
        ("implicit_midpoint", [0.04, 0.02, 0.01, 0.005]),
    ],
)
def test_convergence_order(method, steps):
    pend = Pendulum()
    y0 = torch.tensor([[1.0, 0.5], [-0.5, 1.5]], dtype=F64)
    t = torch.tensor([0.0, 2.0], dtype=F64)
    ref = _dop853(pend.vector_field, y0, t, tol=1e-13)[-1]
    errors = []
    for h in steps:
        out = odeint(pend.vector_field, y0, t, method=method, step_size=h, rtol=1e-14, atol=1e-14)
        errors.append((out[-1] - ref).abs().max().item())
    slope = np.polyfit(np.log(steps), np.log(errors), 1)[0]
    order = METHODS[method].order
    assert abs(slope - order) < 0.3, f"{method}: fitted order {slope:.3f}, errors {errors}"


@pytest.mark.parametrize("method", ["leapfrog", "implicit_midpoint", "rk4"])
def test_energy_over_1e4_steps(method):
    """Symplectic methods keep ``|H - H0|`` bounded; rk4's grows linearly in time."""
    pend = Pendulum()
    y0 = torch.tensor([[1.0, 1.0], [2.0, 0.0], [0.0, 2.2]], dtype=F64)
    t = torch.arange(10_001, dtype=F64) * 0.05
    out = odeint(pend.vector_field, y0, t, method=method, rtol=1e-9, atol=1e-9)
    dh = (pend.hamiltonian(out) - pend.hamiltonian(y0)).abs()
    first, last = dh[1:1001].mean(0), dh[-1000:].mean(0)
    if method == "rk4":
        assert (last > 5 * first).all(), f"no drift: first {first}, last {last}"
    else:
        assert dh.max() < 2e-2, f"max |H - H0| = {dh.max():.3e}"
        assert (last < 1.1 * first + 1e-9).all(), f"drift: first {first}, last {last}"


def _quartic_oscillator(t, y):
    """``H = p² + q⁴``: the frequency grows with the amplitude."""
    q, p = y.unbind(-1)
    return torch.stack([2 * p, -4 * q**3], dim=-1)


def test_dopri5_controls_error_per_trajectory():
    """Easy rows next to a fast one take the steps they take alone."""
    y0 = torch.tensor([[0.1, 0.0], [0.0, 20.0], [0.3, 0.1]], dtype=F64)
    t = torch.linspace(0, 2, 11, dtype=F64)
    easy, hard = [0, 2], [1]

    def easy_rows(seen):
        def field(t, y):
            seen.append(int((y.abs().amax(-1) < 1).sum()))
            return _quartic_oscillator(t, y)

        return field

    rows_batch, rows_alone = [], []
    both = odeint(easy_rows(rows_batch), y0, t, rtol=1e-9, atol=1e-9)
    alone = odeint(easy_rows(rows_alone), y0[easy], t, rtol=1e-9, atol=1e-9)
    hard_field = Counter(_quartic_oscillator)
    hard_alone = odeint(hard_field, y0[hard], t, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(both[:, easy], alone, rtol=0, atol=1e-12)
    torch.testing.assert_close(both[:, hard], hard_alone, rtol=0, atol=1e-9)
    assert sum(rows_batch) <= 1.02 * sum(rows_alone) + 12, "easy rows evaluated too often"
    assert hard_field.rows > 5 * sum(rows_alone) / 2, "the fast row should need more steps"


def test_dopri5_finished_rows_leave_the_active_set():
    spring = MassSpring()
    y0 = torch.tensor([[1.0, 0.0], [1e3, 0.0]], dtype=F64)
    field = Counter(spring.vector_field)
    odeint(field, y0, torch.tensor([0.0, 1.0], dtype=F64), rtol=1e-10, atol=1e-10)
    assert field.rows < 2 * field.calls, "evaluations on finished rows"


@pytest.mark.parametrize(
    ("method", "kwargs", "tol"),
    [
        ("euler", {"step_size": 1e-3}, 5e-2),
        ("rk4", {"step_size": 1e-2}, 1e-7),
        ("leapfrog", {"step_size": 1e-2}, 1e-12),
        ("implicit_midpoint", {"step_size": 1e-2, "rtol": 1e-13, "atol": 1e-13}, 1e-11),
        ("dopri5", {"rtol": 1e-10, "atol": 1e-10}, 1e-8),
    ],
)
def test_forward_then_backward_returns_to_y0(method, kwargs, tol):
    pend = Pendulum()
    y0 = pend.sample_initial(6, torch.Generator().manual_seed(2))
    t = torch.linspace(0, 2, 5, dtype=F64)
    fwd = odeint(pend.vector_field, y0, t, method=method, **kwargs)
    back = odeint(pend.vector_field, fwd[-1], t.flip(0), method=method, **kwargs)
    torch.testing.assert_close(back.flip(0), fwd, rtol=0, atol=tol)
    err = (back[-1] - y0).abs().max().item()
    assert err < tol, f"{method}: |y(0) - y0| = {err:.3e}"


@pytest.mark.parametrize("method", ALL)
def test_decreasing_t_matches_exact_and_time_dependent_field(method):
    """``dy/dt = (cos t, -y_0)`` from ``t = 2`` back to ``t = -1``; exercises ``t``."""

    def field(t, y):
        return torch.cat([torch.cos(t) * torch.ones_like(y[..., :1]), -y[..., :1]], -1)

    t = torch.linspace(2, -1, 7, dtype=F64)
    y0 = torch.tensor([[0.5, 1.0], [-1.0, 0.0]], dtype=F64)
    kwargs = {"dopri5": {"rtol": 1e-10, "atol": 1e-10}}.get(method, {"step_size": 1e-3})
    if method == "implicit_midpoint":
        kwargs |= {"rtol": 1e-12, "atol": 1e-12}
    if method == "leapfrog":
        kwargs["options"] = {"check_separable": False}
    out = odeint(field, y0, t, method=method, **kwargs)
    c = y0[:, 0] - math.sin(2.0)
    q = torch.sin(t)[:, None] + c
    p = y0[:, 1] + torch.cos(t)[:, None] - math.cos(2.0) - c * (t[:, None] - 2.0)
    tol = {"euler": 1e-2, "dopri5": 1e-8}.get(method, 1e-5)
    torch.testing.assert_close(out, torch.stack([q, p], -1), rtol=0, atol=tol)


@pytest.mark.parametrize("dtype", [F32, F64], ids=["f32", "f64"])
def test_fixed_step_counts(dtype):
    """``ceil(|Δt| / step_size)`` steps per interval, robust to rounding of ``t``; leapfrog
    reuses its last kick (2 evaluations per step, +1 at the start, +1 probe)."""
    spring = MassSpring()
    y0 = torch.ones(3, 2, dtype=dtype)
    t = torch.linspace(0, 1, 11, dtype=dtype)
    expected = {("rk4", 0.1): 4 * 10, ("rk4", 0.03): 4 * 40, ("euler", None): 10}
    for (method, h), calls in expected.items():
        field = Counter(spring.vector_field)
        odeint(field, y0, t, method=method, step_size=h)
        assert field.calls == calls, (method, h, field.calls)
    for check, extra in ((True, 2), (False, 1)):
        field = Counter(spring.vector_field)
        opts = {"check_separable": check}
        odeint(field, y0, t, method="leapfrog", step_size=0.05, options=opts)
        assert field.calls == 2 * 20 + extra
    long_t = torch.linspace(0, 20, 201, dtype=F32)
    field = Counter(spring.vector_field)
    odeint(field, y0, long_t, method="rk4", step_size=0.1)
    assert field.calls == 4 * 200, field.calls


def test_dense_output_matches_coarse_grid():
    pend = Pendulum()
    y0 = pend.sample_initial(5, torch.Generator().manual_seed(3))
    t = torch.linspace(0, 5, 500, dtype=F64)
    fine = odeint(pend.vector_field, y0, t, rtol=1e-9, atol=1e-9)
    coarse = odeint(pend.vector_field, y0, t[[0, -1]], rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(fine[[0, -1]], coarse, rtol=0, atol=1e-9)
    ref = _dop853(pend.vector_field, y0, t)
    err = (fine - ref).abs().max().item()
    assert err < 1e-6, f"dense output error {err:.3e}"


def test_dopri5_first_step_option():
    pend = Pendulum()
    y0 = pend.sample_initial(3, torch.Generator().manual_seed(5))
    t = torch.linspace(0, 2, 3, dtype=F64)
    ref = odeint(pend.vector_field, y0, t, rtol=1e-10, atol=1e-10)
    field = Counter(pend.vector_field)
    out = odeint(field, y0, t, rtol=1e-10, atol=1e-10, options={"first_step": 1e-4})
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-8)
    assert field.calls % 6 == 1, "no extra evaluation for the starting-step heuristic"


def test_unknown_method_lists_valid_names():
    with pytest.raises(ValueError, match="valid methods") as info:
        odeint(MassSpring().vector_field, torch.ones(2), torch.arange(2.0), method="rk45")
    assert all(name in str(info.value) for name in METHODS)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"method": "rk4", "options": {"max_iters": 3}}, "unknown options"),
        ({"method": "dopri5", "step_size": 0.1}, "step_size"),
        ({"method": "rk4", "step_size": -0.1}, "step_size"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        odeint(MassSpring().vector_field, torch.ones(1, 2), torch.arange(3.0), **kwargs)


def test_non_monotone_t_raises():
    with pytest.raises(ValueError, match="strictly"):
        odeint(MassSpring().vector_field, torch.ones(1, 2), torch.tensor([0.0, 1.0, 0.5]))


@pytest.mark.parametrize("method", ALL)
def test_dtype_shape_and_inference_mode(method):
    spring = MassSpring()
    t64 = torch.linspace(0, 1, 4, dtype=F64)
    kwargs = {} if method == "dopri5" else {"step_size": 0.05}
    out32 = odeint(spring.vector_field, torch.tensor([0.3, 0.4]), t64, method=method, **kwargs)
    assert out32.shape == (4, 2) and out32.dtype == F32
    y64 = torch.tensor([0.3, 0.4], dtype=F64)
    with torch.inference_mode():
        out64 = odeint(spring.vector_field, y64, t64.float(), method=method, **kwargs)
    assert out64.shape == (4, 2) and out64.dtype == F64
    torch.testing.assert_close(out32, out64.float(), rtol=0, atol=1e-5)
    one = odeint(spring.vector_field, torch.ones(3, 2), t64[:1], method=method)
    assert one.shape == (1, 3, 2)


def test_rk4_gradient_matches_rotation():
    """``∂y(T)/∂y0`` of the spring ``H = q² + p²`` is the rotation by ``ωT``, ``ω = 2``."""
    spring = MassSpring()
    y0 = torch.tensor([[0.3, -0.7]], dtype=F64, requires_grad=True)
    t = torch.tensor([0.0, 0.8], dtype=F64)
    jac = torch.autograd.functional.jacobian(
        lambda y: odeint(spring.vector_field, y, t, method="rk4", step_size=0.01)[-1, 0], y0
    )[:, 0]
    c, s = math.cos(1.6), math.sin(1.6)
    torch.testing.assert_close(jac, torch.tensor([[c, s], [-s, c]], dtype=F64), rtol=0, atol=1e-8)


@pytest.mark.parametrize("method", FIXED)
def test_gradcheck_fixed_step(method):
    pend = Pendulum()
    y0 = torch.tensor([[0.3, -0.7], [1.0, 0.2]], dtype=F64, requires_grad=True)
    t = torch.linspace(0, 1, 3, dtype=F64)

    def solve(y):
        return odeint(pend.vector_field, y, t, method=method, step_size=0.1, rtol=1e-13, atol=1e-13)

    assert torch.autograd.gradcheck(solve, (y0,))


def test_dopri5_gradient_flows_to_y0_and_parameters():
    omega = torch.tensor(2.0, dtype=F64, requires_grad=True)
    y0 = torch.tensor([[1.0, 0.0], [0.0, 0.5]], dtype=F64, requires_grad=True)

    def field(t, y):
        q, p = y.unbind(-1)
        return torch.stack([omega * p, -omega * q], -1)

    t = torch.linspace(0, 1.0, 3, dtype=F64)
    out = odeint(field, y0, t, rtol=1e-10, atol=1e-10)
    out[-1, :, 0].sum().backward()
    c, s = math.cos(2.0), math.sin(2.0)
    torch.testing.assert_close(
        y0.grad, torch.tensor([[c, s], [c, s]], dtype=F64), atol=1e-7, rtol=0
    )
    q0, p0 = y0.detach().unbind(-1)
    expected = (-q0 * s + p0 * c).sum()
    torch.testing.assert_close(omega.grad, expected, atol=1e-7, rtol=0)


def test_leapfrog_warns_on_non_separable_field():
    def field(t, y):
        q, p = y.unbind(-1)
        return torch.stack([2 * q**2 * p, -2 * q * p**2], -1)

    y0 = torch.tensor([[0.5, 0.7]], dtype=F64)
    t = torch.linspace(0, 1, 3, dtype=F64)
    with pytest.warns(UserWarning, match="implicit_midpoint"):
        odeint(field, y0, t, method="leapfrog", step_size=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        odeint(field, y0, t, method="leapfrog", step_size=0.01, options={"check_separable": False})


def test_leapfrog_quiet_on_separable_fields():
    t = torch.linspace(0, 1, 3, dtype=F64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for system in (Pendulum(), MassSpring()):
            for dtype in (F32, F64):
                y0 = system.sample_initial(100, torch.Generator().manual_seed(0)).to(dtype)
                odeint(system.vector_field, y0, t.to(dtype), method="leapfrog", step_size=0.1)


def test_scipy_fun_round_trip():
    pend = Pendulum()
    y0 = pend.sample_initial(4, torch.Generator().manual_seed(4))
    t = torch.linspace(0, 3, 7, dtype=F64)
    fun = scipy_fun(pend.vector_field, (4, 2))
    dy = fun(0.0, y0.reshape(-1).numpy())
    assert isinstance(dy, np.ndarray) and dy.dtype == np.float64 and dy.shape == (8,)
    np.testing.assert_array_equal(dy, pend.vector_field(None, y0).reshape(-1).numpy())
    ref = _dop853(pend.vector_field, y0, t)
    out = odeint(pend.vector_field, y0, t, rtol=1e-11, atol=1e-11)
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-8)
    fun32 = scipy_fun(pend.vector_field, (4, 2), dtype=F32)
    assert np.abs(fun32(0.0, y0.reshape(-1).numpy()) - dy).max() < 1e-5


def test_scipy_odeint_matches_analytic_spring_and_reports_failure():
    spring = MassSpring()
    y0 = _spring_states(5)
    t = torch.linspace(0, 10, 41, dtype=F64)
    out = scipy_odeint(spring.vector_field, y0, t, "DOP853", rtol=1e-12, atol=1e-12)
    assert out.shape == (41, 5, 2) and out.dtype == F64
    torch.testing.assert_close(out, spring.exact_solution(t, y0), rtol=0, atol=1e-9)
    with pytest.raises(RuntimeError, match="RK45"):
        scipy_odeint(lambda t, y: y**2, torch.ones(1, 1, dtype=F64), torch.tensor([0.0, 2.0]))


def test_scipy_fun_takes_the_dtype_of_a_float32_model():
    """The README's ``solve_ivp(scipy_fun(model.vector_field, y0.shape), …)`` on a
    float32 checkpoint: scipy's float64 states are cast to the model's dtype."""
    from scipy.integrate import solve_ivp

    from hnn_pl.models import HNN

    torch.manual_seed(0)
    model = HNN(input_dim=2, hidden_dim=16)
    y0 = torch.tensor([[1.0, 0.0], [0.0, 0.5]])
    fun = scipy_fun(model.vector_field, y0.shape)
    sol = solve_ivp(fun, (0.0, 1.0), y0.flatten().numpy(), rtol=1e-8, atol=1e-8)
    assert sol.success
    with torch.no_grad():
        ours = odeint(model.vector_field, y0, torch.tensor([0.0, 1.0]), rtol=1e-6, atol=1e-6)
    got = torch.from_numpy(sol.y[:, -1]).reshape(2, 2).float()
    torch.testing.assert_close(got, ours[-1], rtol=0, atol=1e-4)


@pytest.mark.parametrize("dtype, tol", [(F32, 2e-4), (F64, 2e-6)], ids=["f32", "f64"])
def test_default_tolerances_fit_the_dtype(dtype, tol):
    """``rtol``/``atol`` left out: float32's defaults (1e-5, 1e-6) are reachable in float32
    and cost a fraction of the field calls of float64's (1e-7, 1e-9), whose accuracy
    float32 cannot deliver anyway."""
    from hnn_pl.integrate import DEFAULT_TOLERANCES

    assert DEFAULT_TOLERANCES[F32] == (1e-5, 1e-6) and DEFAULT_TOLERANCES[F64] == (1e-7, 1e-9)
    spring, y0 = MassSpring(), _spring_states(4)
    t = torch.linspace(0, 20, 200, dtype=F64)
    calls = {}
    for name, kwargs in (("default", {}), ("tight", {"rtol": 1e-7, "atol": 1e-9})):
        field = Counter(spring.vector_field)
        out = odeint(field, y0.to(dtype), t.to(dtype), **kwargs, return_status=True)
        calls[name] = field.calls
        if name == "default":
            assert bool(out.ok.all())
            err = (out.y.double() - spring.exact_solution(t, y0)).abs().max().item()
            assert err < tol, f"{dtype}: max error {err:.2e} >= {tol:.0e}"
    if dtype == F32:
        assert calls["default"] * 2 < calls["tight"], calls
    else:
        assert calls["default"] == calls["tight"]
