"""``python -m hnn_pl bump``: bump a trained HNN's learned energy (:func:`hnn_pl.bump.
energy_bump`) from held-out starts and write ``bump.pt`` and ``bump.png``."""

from __future__ import annotations

from pathlib import Path

import torch

from hnn_pl.bump import energy_bump
from hnn_pl.evaluation import Rollout, view_of
from hnn_pl.plotting import pyplot


def main(argv: list[str] | None = None) -> int:
    """``hnn-pl bump --config X --ckpt_path C [--delta D] …``: bump the held-out
    starts of a trained HNN and write ``bump.pt`` and ``bump.png`` into its run."""
    from hnn_pl.argtypes import integer_at_least, positive_int
    from hnn_pl.commands.cli import _run_directory, cli_main, resolve_checkpoint
    from hnn_pl.commands.cli_errors import (
        CLIError,
        OneLineParser,
        finite_float,
        output_directory,
        positive_float,
        program_name,
    )
    from hnn_pl.commands.config_paths import resolve_config
    from hnn_pl.safe_io import check_model_class, load_checkpoint, save_atomic

    parser = OneLineParser(prog=f"{program_name()} bump", description=main.__doc__)
    parser.add_argument("--config", required=True, help="the config the model was trained with")
    parser.add_argument(
        "--ckpt_path", required=True, help="a checkpoint of an HNN model, or its run (as fit's)"
    )
    parser.add_argument(
        "--delta",
        type=finite_float,
        default=None,
        help="ΔH_θ, a finite number (default: 20 %% of the spread of H_θ over the bumped "
        "starts plus their mean |H_θ|: 0.2 (max H − min H + mean |H|))",
    )
    parser.add_argument(
        "--t_end", type=positive_float, default=10.0, help="rollout horizon > 0 (default: 10)"
    )
    parser.add_argument(
        "--n_points",
        type=integer_at_least(2),
        default=200,
        help="rollout times from 0 to t_end, >= 2 (default: 200)",
    )
    parser.add_argument(
        "--starts", type=positive_int, default=4, help="held-out starts to bump (default: 4)"
    )
    parser.add_argument(
        "--out",
        type=output_directory,
        default=None,
        help="a directory (default: the checkpoint's run, else the checkpoint's directory)",
    )
    args = parser.parse_args(argv)
    config = resolve_config(args.config)
    args.ckpt_path = resolve_checkpoint(args.ckpt_path)
    ckpt = load_checkpoint(args.ckpt_path)
    cli = cli_main(["--config", config, "--trainer.logger=false"], run=False, save_config=False)
    check_model_class(ckpt, cli.config.get("model").class_path, f"checkpoint {args.ckpt_path}")
    model, dm = cli.model, cli.datamodule
    model.load_trained(ckpt, dm, f"checkpoint {args.ckpt_path}")  # as fit saved it: states too
    model.eval()
    dm.setup("test")
    held_out = view_of(model).starts(dm)
    if args.starts > len(held_out):
        raise CLIError(f"--starts {args.starts}: the data holds {len(held_out)} held-out starts")
    starts = held_out[: args.starts]
    t = torch.linspace(0, args.t_end, args.n_points, dtype=torch.float64)
    _, before = energy_bump(model, starts, 0.0, t)
    delta = args.delta
    if delta is None:
        delta = 0.2 * float(
            before.h_pred[0].max() - before.h_pred[0].min() + before.h_pred[0].abs().mean()
        )
    _, after = energy_bump(model, starts, delta, t)
    out = args.out or _run_directory(args.ckpt_path) or Path(args.ckpt_path).resolve().parent
    out.mkdir(parents=True, exist_ok=True)
    save_atomic(
        {"delta": delta, "before": before.as_dict(), "after": after.as_dict()}, out / "bump.pt"
    )
    _figure(before, after, delta, out / "bump.png")
    print(f"bumped H_θ by {delta:.4g}: wrote {out / 'bump.pt'} and {out / 'bump.png'}")
    return 0


def _figure(before: Rollout, after: Rollout, delta: float, path) -> None:
    plt = pyplot()

    if before.x_pred is not None:
        n = min(8, before.x_pred.shape[0])
        idx = torch.linspace(0, before.x_pred.shape[0] - 1, n).long()
        side = int(round((before.x_pred.shape[-1] // 2) ** 0.5))
        fig, axes = plt.subplots(2, n, figsize=(1.4 * n, 3.2))
        for row, (traj, label) in enumerate(((before, "original"), (after, f"ΔH_θ = {delta:.3g}"))):
            for col, k in enumerate(idx.tolist()):
                frame = traj.x_pred[k, 0, : side * side].reshape(side, side).float()
                axes[row, col].imshow(frame.detach().numpy(), cmap="gray")
                axes[row, col].axis("off")
            axes[row, 0].set_title(label, fontsize=8, loc="left")
    else:
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.4))
        for traj, style in ((before, "-"), (after, "--")):
            k = traj.y_pred.shape[-1] // 2
            for b in range(traj.y_pred.shape[1]):
                ax1.plot(traj.y_pred[:, b, 0], traj.y_pred[:, b, k], style, color=f"C{b % 10}")
                ax2.plot(traj.t, traj.h_pred[:, b], style, color=f"C{b % 10}")
        ax1.set(xlabel="q", ylabel="p", title="learned dynamics before and after the bump")
        ax2.set(xlabel="t", ylabel="H_θ", title="H_θ: moved by ΔH, then kept")
        styles = [
            plt.Line2D([], [], color="k", ls="-", label="original (one colour per start)"),
            plt.Line2D([], [], color="k", ls="--", label=f"bumped by ΔH_θ = {delta:.3g}"),
        ]
        fig.legend(handles=styles, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0 if before.x_pred is not None else 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
