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


def test_float64_states_roll_out_a_float32_model():
    """A float32 checkpoint takes float64 starts everywhere a user passes them: the field
    runs in the model's dtype and answers in the states'."""
    import hnn_pl

    torch.manual_seed(0)
    for model in (HNN(input_dim=2, hidden_dim=16), Baseline(input_dim=2, hidden_dim=16)):
        y64 = torch.tensor([[1.0, 0.0], [0.0, 0.5]], dtype=torch.float64)
        t = torch.linspace(0, 1, 5, dtype=torch.float64)
        with torch.no_grad():
            out64 = hnn_pl.odeint(model.vector_field, y64, t, method="rk4")
            out32 = hnn_pl.odeint(model.vector_field, y64.float(), t.float(), method="rk4")
        assert out64.dtype == torch.float64 and out32.dtype == torch.float32
        torch.testing.assert_close(out64.float(), out32, rtol=0, atol=1e-5)
        assert model.rollout(y64, t, method="rk4").dtype == torch.float32


def test_float64_frames_encode_and_decode_in_a_float32_pixel_model():
    from hnn_pl import AutoencoderHNN

    model = AutoencoderHNN(input_dim=8, hidden_dim=8, field_hidden_dim=8)
    x = torch.rand(3, 8, dtype=torch.float64)
    z = model.encode(x)
    assert z.dtype == torch.float64 and model.decode(z).dtype == torch.float64
    torch.testing.assert_close(z.float(), model.encode(x.float()))


def test_submodules_are_attributes_after_import_hnn_pl():
    """``import hnn_pl`` then ``hnn_pl.bump.energy_bump``, as the README writes it."""
    import subprocess
    import sys

    code = "import hnn_pl; hnn_pl.bump.energy_bump; hnn_pl.integrate.scipy_fun"
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("objective", ["derivative", "trajectory"])
def test_the_l1_loss_is_the_mean_absolute_error_of_either_objective(objective):
    """``loss: l1``: ``train/loss`` is ``mean |pred − target|`` (``mse``: its square's
    mean), on derivative pairs and on windows alike."""
    torch.manual_seed(0)
    models = {
        n: HNN(input_dim=4, hidden_dim=16, loss=n, objective=objective) for n in ("mse", "l1")
    }
    models["l1"].load_state_dict(models["mse"].state_dict())
    if objective == "derivative":
        y, target = torch.randn(9, 4), torch.randn(9, 4)
        batch, pred = (y, target), models["mse"](y)
    else:
        y, t = torch.randn(9, 3, 4), torch.linspace(0, 0.2, 3).expand(9, 3)
        batch = (y, t, torch.arange(27).view(9, 3))
        pred, target = models["mse"].integrate_windows(y[:, 0], t)[:, 1:], y[:, 1:]
    for name, want in (
        ("mse", (pred - target).square().mean()),
        ("l1", (pred - target).abs().mean()),
    ):
        torch.testing.assert_close(models[name].training_loss(batch)["loss"], want)
    with pytest.raises(ValueError, match="loss must be one of"):
        HNN(input_dim=4, loss="huber")
