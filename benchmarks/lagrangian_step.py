"""Cost of one training step of the Lagrangian and mass-matrix-structured models beside the HNN.

One step = ``zero_grad``, the model's loss, ``backward``, Adam, at width 200, batch 200, a
2-degree-of-freedom state (``D = 4``), float32, 1 thread. Derivative objective: the HNN's
``MSE(J∇H_θ(y), dy/dt)``, the Lagrangian models' ``MSE(q̈_θ(q, q̇), q̈)``, the structured
HNN's ``MSE(f_θ(y), dy/dt)``. Trajectory objective: 5-sample windows (4 RK4 steps) from
each window's observed start, ``MSE`` of the integrated states. The LNN (with its default
kinetic prior ``c = 1``) three ways: Hessian blocks in closed form (the model's, for its
tanh MLP), by ``torch.func`` forward-over-reverse (any ``L``) and by double autograd. The
structured models with their defaults (the factor of ``M_θ⁻¹``; ``M_θ⁻¹`` and ``V_θ`` as
two heads of one MLP) and with two MLPs. Targets (issue 33): LNN ≤ 3× HNN, the
structured models ≤ 2× HNN.
"""

from __future__ import annotations

import sys

import torch
from common import main, measure, ms, table

from hnn_pl.integrate import odeint_windows
from hnn_pl.nets import MLP, HamiltonianField
from hnn_pl.nets.lagrangian import (
    LagrangianField,
    MechanicalHamiltonianField,
    MechanicalLagrangianField,
    MechanicalNets,
    lagrangian_terms,
    lagrangian_terms_autograd,
)

TITLE = "Lagrangian and structured models: training step"
BATCH, DOF, WIDTH, WINDOW = 200, 2, 200, 5
KINDS = ("HNN", "LNN", "LNN (torch.func)", "LNN (double autograd)", "MechanicalHNN")
KINDS += ("MechanicalLNN", "MechanicalHNN (two MLPs)", "MechanicalLNN (two MLPs)")
#: the kinds trained on accelerations (Lagrangian)
LAGRANGIAN = {k for k in KINDS if "LNN" in k}


def make_field(kind: str) -> torch.nn.Module:
    torch.manual_seed(0)
    d = 2 * DOF
    if kind == "HNN":
        return HamiltonianField(MLP(d, 1, WIDTH))
    if kind == "LNN":
        return LagrangianField(MLP(d, 1, WIDTH), kinetic_prior=1.0)
    if kind == "LNN (torch.func)":
        return LagrangianField(MLP(d, 1, WIDTH), 1.0, terms=lagrangian_terms)
    if kind == "LNN (double autograd)":
        return LagrangianField(MLP(d, 1, WIDTH), 1.0, terms=lagrangian_terms_autograd)
    nets = MechanicalNets(DOF, WIDTH, 2, "tanh", shared="two MLPs" not in kind, inverse=True)
    if kind.startswith("MechanicalHNN"):
        return MechanicalHamiltonianField(nets)
    return MechanicalLagrangianField(nets)


def derivative_loss(kind: str, field, y: torch.Tensor, target: torch.Tensor):
    if kind in LAGRANGIAN:
        q, v = y.chunk(2, -1)
        return lambda: torch.nn.functional.mse_loss(field.acceleration(q, v), target[:, DOF:])
    return lambda: torch.nn.functional.mse_loss(field.vector_field(None, y), target)


def trajectory_loss(kind: str, field, y: torch.Tensor, t: torch.Tensor):
    f = field.native_vector_field if kind in LAGRANGIAN else field.vector_field

    def loss():
        pred = odeint_windows(f, y[:, 0], t, "rk4", 1)
        return torch.nn.functional.mse_loss(pred[:, 1:], y[:, 1:])

    return loss


def make_step(field, loss):
    """``zero_grad``, ``loss()``, ``backward``, Adam step."""
    opt = torch.optim.Adam(field.parameters(), lr=1e-3)

    def step():
        opt.zero_grad(set_to_none=True)
        loss().backward()
        opt.step()

    return step


def data():
    g = torch.Generator().manual_seed(0)
    y, dy = torch.randn(BATCH, 2 * DOF, generator=g), torch.randn(BATCH, 2 * DOF, generator=g)
    windows = 0.5 * torch.randn(BATCH, WINDOW, 2 * DOF, generator=g)
    t = 0.03 * torch.arange(WINDOW, dtype=torch.float32).expand(BATCH, WINDOW)
    return y, dy, windows, t


def step_times(quick: bool) -> dict[str, dict[str, float]]:
    """Median seconds per step, ``{objective: {kind: s}}``."""
    y, dy, windows, t = data()
    mrt = 0.1 if quick else 0.5
    out: dict[str, dict[str, float]] = {"derivative": {}, "trajectory": {}}
    for kind in KINDS:
        field = make_field(kind)
        out["derivative"][kind] = measure(
            make_step(field, derivative_loss(kind, field, y, dy)), mrt
        )[0]
        field = make_field(kind)
        out["trajectory"][kind] = measure(
            make_step(field, trajectory_loss(kind, field, windows, t)), mrt
        )[0]
    return out


def run(quick: bool) -> str:
    times = step_times(quick)
    rows = []
    for kind in KINDS:
        d, tr = times["derivative"][kind], times["trajectory"][kind]
        hd, ht = times["derivative"]["HNN"], times["trajectory"]["HNN"]
        rows.append([kind, ms(d), f"{d / hd:.2f}", ms(tr), f"{tr / ht:.2f}"])
    return (
        f"One Adam step at batch {BATCH}, width {WIDTH} (two hidden layers), {DOF} degrees of "
        f"freedom, float32, 1 thread; trajectory: {WINDOW}-sample windows, RK4. Median of "
        "`blocked_autorange`. Ratios against the HNN of the same objective.\n\n"
        + table(
            "model | derivative step (ms) | × HNN | trajectory step (ms) | × HNN",
            rows,
        )
    )


if __name__ == "__main__":
    main({"lagrangian": sys.modules[__name__]}, None)
