"""The learned fields: closed-form HNN gradient, Hamiltonian structure, modes."""

from __future__ import annotations

import pytest
import torch

from hnn_pl import HNN, Baseline
from hnn_pl.nets import MLP, HamiltonianField


def _autograd_grad(net, y, create_graph=False):
    y = y.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(net(y)[:, 0].sum(), y, create_graph=create_graph)
    return g


@pytest.mark.parametrize("dim", [2, 8])
def test_closed_form_gradient_equals_autograd(dim):
    torch.manual_seed(0)
    net = MLP(dim, 1).double()
    y = torch.randn(64, dim, dtype=torch.float64)
    value, grad = net.value_and_input_grad(y)
    torch.testing.assert_close(value, net(y)[:, 0], rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(grad, _autograd_grad(net, y), rtol=1e-12, atol=1e-12)


def test_closed_form_training_gradient_equals_double_backward():
    """The parameter gradient of the HNN loss is the same by both paths."""
    torch.manual_seed(1)
    closed = HamiltonianField(MLP(4, 1).double())
    auto = HamiltonianField(MLP(4, 1).double(), closed_form=False)
    auto.load_state_dict(closed.state_dict())
    y, target = torch.randn(32, 4, dtype=torch.float64), torch.randn(32, 4, dtype=torch.float64)
    grads = []
    for field in (closed, auto):
        loss = ((field(y) - target) ** 2).mean()
        grads.append(torch.autograd.grad(loss, list(field.parameters())))
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("closed_form", [True, False])
def test_hnn_field_is_hamiltonian(closed_form):
    """J∇H: gradcheck passes, the divergence vanishes, and H is conserved to first order."""
    torch.manual_seed(2)
    field = HamiltonianField(MLP(4, 1, hidden_dim=32).double(), closed_form=closed_form)
    y = torch.randn(5, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(field, (y,))
    jac = torch.autograd.functional.jacobian(lambda z: field(z[None])[0], y[0].detach())
    assert abs(torch.trace(jac)) < 1e-12
    with torch.no_grad():
        f = field(y)
    h, g = field.value_and_grad(y.detach())
    assert (g * f).sum(-1).abs().max() < 1e-12


@pytest.mark.parametrize("closed_form", [True, False])
def test_hnn_field_under_inference_mode(closed_form):
    torch.manual_seed(3)
    field = HamiltonianField(MLP(2, 1), closed_form=closed_form)
    y = torch.randn(10, 2)
    expected = field(y).detach()
    with torch.inference_mode():
        got = field(torch.randn(10, 2) * 0 + y)
    torch.testing.assert_close(got, expected)


def test_models_shapes_and_hparams():
    hnn, base = HNN(input_dim=8, hidden_dim=16), Baseline(input_dim=8, hidden_dim=16)
    y = torch.randn(7, 8)
    assert hnn(y).shape == base(y).shape == (7, 8)
    assert hnn.hamiltonian(y).shape == (7,)
    assert hnn.hparams.input_dim == 8 and base.hparams.hidden_dim == 16
    assert hnn.field.net.out.bias is None
    w = hnn.field.net.hidden[1].weight
    torch.testing.assert_close(w @ w.T, torch.eye(16), atol=1e-5, rtol=0)
