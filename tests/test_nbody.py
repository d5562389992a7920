"""Gravitational n-body systems: field, invariants, reference sampling, ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from hnn_pl.systems.base import symplectic_gradient
from hnn_pl.systems.nbody import NBody, from_reference_order, rotate2d, to_reference_order
from hnn_pl.systems.three_body import ThreeBody
from hnn_pl.systems.two_body import TwoBody

F64 = torch.float64
SYSTEMS = {
    "two": TwoBody(),
    "three": ThreeBody(),
    "five-unequal": NBody(5, masses=[1.0, 2.0, 0.5, 3.0, 1.5], G=0.7),
}
#: paper horizons: (t_end, points)
HORIZON = {"two": (20.0, 50), "three": (5.0, 20)}


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def random_states(system: NBody, shape: tuple[int, ...], seed: int = 0) -> torch.Tensor:
    """Random states with all pair distances ≥ 0.3 (well away from the singularity)."""
    g = gen(seed)
    y = torch.randn(*shape, system.state_dim, generator=g, dtype=F64)
    while True:
        bad = system.pair_distances(y).min(-1).values < 0.3
        if not bad.any():
            return y
        y[bad] = torch.randn(int(bad.sum()), system.state_dim, generator=g, dtype=F64)


def reference_update(state: np.ndarray) -> np.ndarray:
    """The reference code's ``update`` (G = 1): rows ``[m, x, y, vx, vy]`` per body."""
    deriv = np.zeros_like(state)
    deriv[:, 1:3] = state[:, 3:5]
    for i in range(state.shape[0]):
        other = np.concatenate([state[:i], state[i + 1 :]], axis=0)
        disp = other[:, 1:3] - state[i, 1:3]
        dist = (disp**2).sum(1, keepdims=True) ** 0.5
        deriv[i, 3:5] = (other[:, 0:1] * disp / dist**3).sum(0)
    return deriv


# ------------------------------------------------------------------ vector field
@pytest.mark.parametrize("name", list(SYSTEMS))
def test_vector_field_is_symplectic_gradient_of_h(name):
    system = SYSTEMS[name]
    y = random_states(system, (4, 3)).requires_grad_(True)
    (grad,) = torch.autograd.grad(system.hamiltonian(y).sum(), y)
    expected = symplectic_gradient(grad)
    got = system.vector_field(None, y.detach())
    assert got.shape == y.shape == (4, 3, 4 * system.n_bodies)
    torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["two", "three"])
def test_vector_field_matches_reference_update(name):
    """Same field as the reference's loop code, in its coordinate order (G = m = 1)."""
    system = SYSTEMS[name]
    n = system.n_bodies
    for y in random_states(system, (5,), seed=1):
        q, p = system.split(y)
        state = np.concatenate([np.ones((n, 1)), q.numpy(), p.numpy()], axis=1)
        coords = state.T[1:].flatten()
        dcoords = reference_update(state).T[1:].flatten()
        np.testing.assert_array_equal(to_reference_order(y).numpy(), coords)
        got = to_reference_order(system.vector_field(None, y)).numpy()
        np.testing.assert_allclose(got, dcoords, rtol=1e-13, atol=1e-13)


def test_hamiltonian_and_invariants_by_hand():
    system = NBody(2, masses=[1.0, 3.0], G=2.0)
    # x1, y1, x2, y2, px1, py1, px2, py2
    y = torch.tensor([0.0, 0.0, 3.0, 4.0, 1.0, 2.0, -3.0, 0.0], dtype=F64)
    # T = (1 + 4)/2 + 9/6 = 4, V = −2·1·3/5
    assert system.hamiltonian(y).item() == pytest.approx(4.0 - 6.0 / 5.0, abs=1e-15)
    torch.testing.assert_close(system.momentum(y), torch.tensor([-2.0, 2.0], dtype=F64))
    # L = (0·2 − 0·1) + (3·0 − 4·(−3)) = 12
    assert system.angular_momentum(y).item() == pytest.approx(12.0, abs=1e-15)
    torch.testing.assert_close(system.centre_of_mass(y), torch.tensor([2.25, 3.0], dtype=F64))
    f = system.vector_field(0.0, y)
    # dq = p/m; dp_1 = G m1 m2 (q2 − q1)/|q2 − q1|³ = 6·(3, 4)/125, dp_2 = −dp_1
    expected = [1.0, 2.0, -1.0, 0.0, 18 / 125, 24 / 125, -18 / 125, -24 / 125]
    torch.testing.assert_close(f, torch.tensor(expected, dtype=F64), rtol=1e-15, atol=1e-15)
    assert system.energy(y).item() == system.hamiltonian(y).item()


def test_reference_order_permutation():
    y = torch.arange(12.0)  # three bodies: x1 y1 x2 y2 x3 y3 | px1 py1 px2 py2 px3 py3
    ref = to_reference_order(y)
    assert ref.tolist() == [0, 2, 4, 1, 3, 5, 6, 8, 10, 7, 9, 11]
    batch = torch.randn(2, 3, 8, dtype=F64)
    torch.testing.assert_close(from_reference_order(to_reference_order(batch)), batch)
    assert not torch.equal(to_reference_order(batch), batch)


# ---------------------------------------------------------------------- sampling
@pytest.mark.parametrize("name", ["two", "three"])
def test_sampling_shape_dtype_determinism(name):
    system = SYSTEMS[name]
    a = system.sample_initial(64, gen(3))
    assert a.shape == (64, 4 * system.n_bodies) and a.dtype == F64
    assert torch.isfinite(a).all()
    torch.testing.assert_close(system.sample_initial(64, gen(3)), a, rtol=0, atol=0)
    assert not torch.allclose(system.sample_initial(64, gen(4)), a)


def test_two_body_sampling_statistics():
    system, n = SYSTEMS["two"], 20000
    y = system.sample_initial(n, gen(5))
    q, p = system.split(y)
    # body 1 = −body 0 exactly; centre of mass and total momentum exactly zero
    torch.testing.assert_close(q[:, 1], -q[:, 0], rtol=0, atol=0)
    torch.testing.assert_close(p[:, 1], -p[:, 0], rtol=0, atol=0)
    assert system.momentum(y).abs().max() == 0 and system.centre_of_mass(y).abs().max() == 0
    # each coordinate of body 0 ~ U[0.5, 1.5]: range, mean 1, std 1/√12
    assert q[:, 0].min() >= 0.5 and q[:, 0].max() <= 1.5
    assert q[:, 0].min() < 0.51 and q[:, 0].max() > 1.49
    torch.testing.assert_close(q[:, 0].mean(0), torch.ones(2, dtype=F64), atol=0.01, rtol=0)
    torch.testing.assert_close(
        q[:, 0].std(0), torch.full((2,), 12**-0.5, dtype=F64), atol=0.005, rtol=0
    )
    # velocity ⟂ position, counter-clockwise, speed = circular speed·(1 + 0.05 N(0,1))
    r = q[:, 0].norm(dim=-1)
    v = p[:, 0]  # m = 1
    torch.testing.assert_close((v * q[:, 0]).sum(-1), torch.zeros(n, dtype=F64), atol=1e-15, rtol=0)
    assert (system.angular_momentum(y) > 0).all()
    factor = v.norm(dim=-1) / (1 / (2 * r.sqrt()))
    assert stats.kstest(factor.numpy(), stats.norm(1.0, 0.05).cdf).pvalue > 1e-3
    assert abs(factor.mean().item() - 1) < 0.002
    assert abs(factor.std().item() - 0.05) < 0.002
    # one noise draw per orbit: independent of the position
    assert abs(torch.corrcoef(torch.stack([factor, r]))[0, 1].item()) < 0.03


def test_three_body_sampling_statistics():
    system, n = SYSTEMS["three"], 20000
    y = system.sample_initial(n, gen(6))
    q, p = system.split(y)
    radii = q.norm(dim=-1)  # (n, 3): one radius per orbit
    torch.testing.assert_close(radii, radii[:, :1].expand(-1, 3), rtol=1e-14, atol=0)
    r = radii[:, 0]
    assert r.min() >= 0.9 and r.max() <= 1.2 and r.min() < 0.901 and r.max() > 1.199
    assert abs(r.mean().item() - 1.05) < 0.002
    # direction of body 0: a normalised U[−1, 1]² draw (as the reference), not a uniform
    # angle: P(angle within π/8 of a diagonal) = 1 − tan(π/8) ≈ 0.586 (uniform: 0.5)
    angle = torch.atan2(q[:, 0, 1], q[:, 0, 0]) % (math.pi / 2)
    near_diagonal = ((angle - math.pi / 4).abs() < math.pi / 8).double().mean().item()
    assert abs(near_diagonal - (1 - math.tan(math.pi / 8))) < 0.015
    # bodies 120° apart counter-clockwise; centre of mass at zero
    for k in (1, 2):
        torch.testing.assert_close(q[:, k], rotate2d(q[:, 0], 2 * math.pi * k / 3))
    assert system.centre_of_mass(y).abs().max() < 1e-15
    # velocity components = circular velocity · (1 + 0.2 U(−1, 1)), all six independent
    v_circ = rotate2d(q, math.pi / 2) / (3**0.25 * r[:, None, None] ** 1.5)
    ok = (v_circ.abs() > 0.05).flatten(1).all(-1)
    factor = (p / v_circ)[ok].flatten(1)  # (rows, 6)
    assert ok.sum() > n // 2
    assert factor.min() >= 0.8 - 1e-12 and factor.max() <= 1.2 + 1e-12
    assert stats.kstest(factor.flatten().numpy(), stats.uniform(0.8, 0.4).cdf).pvalue > 1e-3
    corr = torch.corrcoef(factor.T)
    assert (corr - torch.eye(6, dtype=F64)).abs().max() < 0.03
    # the noise does not preserve total momentum (as in the reference), bounded by it
    P = system.momentum(y)
    assert P.abs().max() > 0.05
    assert (P.abs() <= 0.2 * v_circ.abs().sum(-2) + 1e-12).all()


def test_circular_velocity_generalises_to_g_and_mass():
    """For G·m ≠ 1 the noise-free ring is still a circular (stationary-radius) orbit."""
    for k in (2, 3, 4, 6):
        system = NBody(k, masses=2.5, G=0.4, orbit_noise=0.0)
        y = system.sample_initial(3, gen(k))
        q, p = system.split(y)
        dp = system.split(system.vector_field(None, y))[1]
        # centripetal: force = −m v² / r · q̂, i.e. dp = −|p|²/(m r²) · q
        expected = (
            -(p.square().sum(-1, keepdim=True) / (2.5 * q.square().sum(-1, keepdim=True))) * q
        )
        torch.testing.assert_close(dp, expected, rtol=1e-12, atol=1e-14)


def test_unequal_masses_cannot_sample():
    with pytest.raises(ValueError):
        NBody(3, masses=[1.0, 2.0, 3.0]).sample_initial(2, gen())


# ------------------------------------------------------------------ ground truth
@pytest.mark.parametrize("name", ["two", "three"])
def test_ground_truth_conserves_invariants(name):
    system = SYSTEMS[name]
    t_end, points = HORIZON[name]
    y0 = system.sample_initial(8, gen(7))
    t = torch.linspace(0, t_end, points, dtype=F64)
    ys = system.trajectory(y0, t)
    assert ys.shape == (points, 8, 4 * system.n_bodies) and ys.dtype == F64
    torch.testing.assert_close(ys[0], y0, rtol=0, atol=0)
    h = system.energy(ys)
    assert ((h - h[0]).abs() / h[0].abs()).max() < 1e-8
    assert (system.momentum(ys) - system.momentum(y0)).abs().max() < 1e-9
    ang = system.angular_momentum(ys)
    assert ((ang - ang[0]).abs() / ang[0].abs()).max() < 1e-8
    # the orbits do move: the positions change by O(1) over the horizon
    assert (ys[-1] - ys[0]).abs().max() > 0.5


def test_two_body_circular_orbit_is_exact_rotation():
    """Noise off: each body circles at ω = √(G m / 4 r³), radius constant."""
    system = TwoBody(orbit_noise=0.0)
    y0 = system.sample_initial(4, gen(8))
    t = torch.linspace(0, 20, 50, dtype=F64)
    ys = system.trajectory(y0, t)
    q0, p0 = system.split(y0)
    r = q0[:, 0].norm(dim=-1)
    omega = (1 / (4 * r**3)).sqrt()
    theta = t[:, None, None] * omega[None, :, None]  # (T, n, 1) broadcast over bodies
    q_exact = rotate2d(q0[None], theta)
    p_exact = rotate2d(p0[None], theta)
    q, p = system.split(ys)
    torch.testing.assert_close(
        q.norm(dim=-1), r[None, :, None].expand(50, -1, 2), rtol=1e-8, atol=0
    )
    torch.testing.assert_close(q, q_exact, rtol=0, atol=1e-7)
    torch.testing.assert_close(p, p_exact, rtol=0, atol=1e-7)
