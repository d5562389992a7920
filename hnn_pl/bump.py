"""Energy bump (Greydanus et al. 2019, §6): change a trajectory's learned energy ``H_θ``
by a requested amount, then follow the learned dynamics at the new energy.

The bump integrates the normalised gradient flow ``dy/ds = ∇H_θ(y) / |∇H_θ(y)|²``, on
which ``dH_θ/ds = 1``, from ``s = 0`` to ``s = ΔH`` (backward for ``ΔH < 0``), so
``H_θ(y(ΔH)) = H_θ(y₀) + ΔH`` up to the integration's tolerance; the rollout then
integrates ``dy/dt = J ∇H_θ(y)``, which keeps ``H_θ``. ``∇H_θ`` comes from the
field's own ``J ∇H_θ``: with ``J∇H = (∂H/∂p, −∂H/∂q)``, ``∇H = (−(J∇H)_p, (J∇H)_q)``.
Pixel models are bumped in their latent space and decoded.
"""

from __future__ import annotations

import copy
from typing import Any

import torch
from torch import Tensor, nn

from hnn_pl.integrate import odeint
from hnn_pl.rollouts import Trajectories, is_pixel_model, rollout


class GradientFlow(nn.Module):
    """``dy/ds = ∇H_θ / |∇H_θ|²`` of a Hamiltonian field (``(B, D) -> (B, D)``)."""

    def __init__(self, field: nn.Module) -> None:
        super().__init__()
        self.field = field

    def vector_field(self, s: Tensor, y: Tensor) -> Tensor:
        f = self.field.vector_field(s, y)
        k = f.shape[-1] // 2
        grad = torch.cat([-f[..., k:], f[..., :k]], -1)
        return grad / grad.square().sum(-1, keepdim=True).clamp_min(1e-300)


def energy_bump(
    model: Any,
    y0: Tensor,
    delta: float,
    t: Tensor,
    method: str = "dopri5",
    rtol: float = 1e-10,
    atol: float = 1e-10,
) -> tuple[Tensor, Trajectories]:
    """Bump ``H_θ`` of each start by ``delta``, then roll out over ``t``.

    Args:
        model: an HNN (state or pixel); its field must have ``hamiltonian``.
        y0: ``(B, D)`` states, or ``(B, input_dim)`` frame pairs for a pixel model.
        delta: the change of ``H_θ``.
        t: ``(T,)`` rollout times after the bump.
        method, rtol, atol: the rollout's integrator (the bump uses float64 dopri5 at
            ``rtol``/``atol``).

    Returns:
        ``(z_bumped (B, D), trajectories)``: the bumped (latent) states and the rollout
        from them (:class:`hnn_pl.rollouts.Trajectories`; ``h`` is ``H_θ`` along it,
        pixel models also ``frames``).
    """
    field = getattr(model, "field", model)
    if not hasattr(field, "hamiltonian"):
        raise ValueError(f"{type(model).__name__} learns no H_θ: only HNN models can be bumped")
    field64 = copy.deepcopy(field).double().eval()
    with torch.no_grad():
        z0 = model.encode(y0) if is_pixel_model(model) else y0
        s = torch.tensor([0.0, float(delta)], dtype=torch.float64)
        if delta == 0:
            z1 = z0.double()
        else:
            flow = GradientFlow(field64)
            sol = odeint(
                flow.vector_field, z0.double(), s, rtol=rtol, atol=atol, return_status=True
            )
            if not bool(sol.ok.all()):
                rows = (~sol.ok).nonzero().flatten().tolist()
                first = float(sol.t_stop[~sol.ok].min())
                raise ValueError(
                    f"energy bump: rows {rows[:5]} meet a critical point of H_θ before it "
                    f"changes by {delta:g} (first at ΔH_θ = {first:.3g}); use a smaller |delta|"
                )
            z1 = sol.y[-1]
    if is_pixel_model(model):
        out = rollout(_LatentModel(model, field64), z1, t, method, rtol=rtol, atol=atol)
    else:
        out = rollout(field64, z1, t, method, rtol=rtol, atol=atol)
    return z1, out


class _LatentModel(nn.Module):
    """A pixel model seen from its latent space: starts are latents, outputs decoded."""

    def __init__(self, model: nn.Module, field: nn.Module) -> None:
        super().__init__()
        self.model, self.field = model, field

    def encode(self, z: Tensor) -> Tensor:
        return z

    def decode(self, z: Tensor) -> Tensor:
        param = next(self.model.parameters())
        return self.model.decode(z.to(param.dtype))


def main(argv: list[str] | None = None) -> int:
    """``hnn-pl bump --config X --ckpt_path C [--delta D] …``: bump the held-out
    starts of a trained HNN and write ``bump.pt`` and ``bump.png`` beside the checkpoint."""
    from pathlib import Path

    from hnn_pl.__main__ import program_name
    from hnn_pl.cli import cli_main, resolve_checkpoint
    from hnn_pl.cli_errors import OneLineParser, check_checkpoint
    from hnn_pl.config_paths import resolve_config
    from hnn_pl.safe_io import load_checkpoint, save_atomic

    parser = OneLineParser(prog=f"{program_name()} bump", description=main.__doc__)
    parser.add_argument("--config", required=True, help="the config the model was trained with")
    parser.add_argument(
        "--ckpt_path", required=True, help="a checkpoint of an HNN model, or its run (as fit's)"
    )
    parser.add_argument(
        "--delta", type=float, default=None, help="ΔH_θ (default: 20 %% of its spread)"
    )
    parser.add_argument("--t_end", type=float, default=10.0, help="rollout horizon after the bump")
    parser.add_argument("--n_points", type=int, default=200)
    parser.add_argument("--starts", type=int, default=4, help="held-out starts to bump")
    parser.add_argument("--out", type=Path, default=None, help="default: the checkpoint's run dir")
    args = parser.parse_args(argv)
    config = resolve_config(args.config)
    args.ckpt_path = resolve_checkpoint(args.ckpt_path)
    ckpt = load_checkpoint(args.ckpt_path)
    cli = cli_main(["--config", config, "--trainer.logger=false"], run=False, save_config=False)
    check_checkpoint(args.ckpt_path, ckpt, cli.config.get("model"))
    state = ckpt.get("state_dict")
    if not isinstance(state, dict):
        raise ValueError(
            f"checkpoint {args.ckpt_path}: holds no state_dict (not a Lightning checkpoint)"
        )
    model, dm = cli.model, cli.datamodule
    model.load_state_dict(state)
    model.eval()
    dm.setup("test")
    if is_pixel_model(model):
        starts = dm.rollout_truth(n_points=2)[2][0][: args.starts]
    else:
        starts = dm.rollout_target()[1][0][: args.starts]
    t = torch.linspace(0, args.t_end, args.n_points, dtype=torch.float64)
    _, before = energy_bump(model, starts, 0.0, t)
    delta = args.delta
    if delta is None:
        delta = 0.2 * float(before.h[0].max() - before.h[0].min() + before.h[0].abs().mean())
    _, after = energy_bump(model, starts, delta, t)
    out = args.out or Path(args.ckpt_path).resolve().parent.parent
    out.mkdir(parents=True, exist_ok=True)
    save_atomic(
        {"delta": delta, "before": before.as_dict(), "after": after.as_dict()}, out / "bump.pt"
    )
    _figure(before, after, delta, out / "bump.png")
    print(f"bumped H_θ by {delta:.4g}: wrote {out / 'bump.pt'} and {out / 'bump.png'}")
    return 0


def _figure(before: Trajectories, after: Trajectories, delta: float, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if before.frames is not None:
        n = min(8, before.frames.shape[0])
        idx = torch.linspace(0, before.frames.shape[0] - 1, n).long()
        side = int(round((before.frames.shape[-1] // 2) ** 0.5))
        fig, axes = plt.subplots(2, n, figsize=(1.4 * n, 3.2))
        for row, (traj, label) in enumerate(((before, "original"), (after, f"ΔH_θ = {delta:.3g}"))):
            for col, k in enumerate(idx.tolist()):
                frame = traj.frames[k, 0, : side * side].reshape(side, side).float()
                axes[row, col].imshow(frame.detach().numpy(), cmap="gray")
                axes[row, col].axis("off")
            axes[row, 0].set_title(label, fontsize=8, loc="left")
    else:
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.4))
        for traj, style in ((before, "-"), (after, "--")):
            k = traj.y.shape[-1] // 2
            for b in range(traj.y.shape[1]):
                ax1.plot(traj.y[:, b, 0], traj.y[:, b, k], style, color=f"C{b % 10}")
                ax2.plot(traj.t, traj.h[:, b], style, color=f"C{b % 10}")
        ax1.set(xlabel="q", ylabel="p", title="learned dynamics before and after the bump")
        ax2.set(xlabel="t", ylabel="H_θ", title="H_θ: moved by ΔH, then kept")
        styles = [
            plt.Line2D([], [], color="k", ls="-", label="original (one colour per start)"),
            plt.Line2D([], [], color="k", ls="--", label=f"bumped by ΔH_θ = {delta:.3g}"),
        ]
        fig.legend(handles=styles, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0 if before.frames is not None else 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
