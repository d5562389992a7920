"""Each system's analytic field equals J∇H computed by autograd."""

from __future__ import annotations

import pytest
import torch

from hnn_pl.systems import MassSpring, Pendulum, symplectic_gradient

SYSTEMS = [MassSpring(), MassSpring(alpha=0.5, beta=0.5), Pendulum(), Pendulum(alpha=2.4)]


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: f"{type(s).__name__}-{s.alpha}")
def test_vector_field_is_symplectic_gradient(system):
    g = torch.Generator().manual_seed(0)
    y = system.sample_initial(100, g).requires_grad_(True)
    (grad,) = torch.autograd.grad(system.hamiltonian(y).sum(), y)
    torch.testing.assert_close(
        system.vector_field(None, y), symplectic_gradient(grad), rtol=1e-12, atol=1e-12
    )


@pytest.mark.parametrize("system", [MassSpring(), Pendulum()], ids=["spring", "pendulum"])
def test_sample_initial_radius_and_determinism(system):
    a = system.sample_initial(2000, torch.Generator().manual_seed(5))
    b = system.sample_initial(2000, torch.Generator().manual_seed(5))
    assert a.shape == (2000, 2) and a.dtype == torch.float64
    assert torch.equal(a, b)
    r = a.norm(dim=-1)
    lo, hi = system.radius
    assert lo <= r.min() and r.max() <= hi
    assert r.min() < lo + 0.01 and r.max() > hi - 0.01


def test_spring_exact_solution_conserves_h_and_solves_the_ode():
    s = MassSpring(alpha=0.7, beta=1.3)
    y0 = s.sample_initial(10, torch.Generator().manual_seed(0))
    t = torch.linspace(0, 5, 101, dtype=torch.float64)
    y = s.exact_solution(t, y0)
    torch.testing.assert_close(y[0], y0)
    torch.testing.assert_close(s.hamiltonian(y), s.hamiltonian(y0).expand(101, -1))
    dt = 1e-6
    dydt = (s.exact_solution(t + dt, y0) - s.exact_solution(t - dt, y0)) / (2 * dt)
    torch.testing.assert_close(dydt, s.vector_field(t, y), rtol=1e-7, atol=1e-8)
