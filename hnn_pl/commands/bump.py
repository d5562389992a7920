"""``python -m hnn_pl bump``: :func:`hnn_pl.bump.energy_bump` from held-out starts, into
``bump.pt`` and ``bump.png``; ``bump --help`` imports neither torch nor Lightning."""

from __future__ import annotations

from pathlib import Path

from hnn_pl.argtypes import (
    finite_float,
    integer_at_least,
    output_directory,
    positive_float,
    positive_int,
)
from hnn_pl.commands.cli_errors import CLIError, OneLineParser, program_name

#: the default ΔH_θ's share (:func:`hnn_pl.bump.default_delta`)
DELTA_SHARE = 0.2


def parser() -> OneLineParser:
    """The options of ``bump``."""
    p = OneLineParser(prog=f"{program_name()} bump", description=main.__doc__)
    p.add_argument("--config", required=True, help="the config the model was trained with")
    p.add_argument(
        "--ckpt_path", required=True, help="a checkpoint of an HNN model, or its run (as fit's)"
    )
    p.add_argument(
        "--delta",
        type=finite_float,
        default=None,
        help=f"ΔH_θ, a finite number (default: {DELTA_SHARE * 100:g} %% of the spread of H_θ "
        f"over the bumped starts plus their mean |H_θ|: {DELTA_SHARE} (max H − min H + mean "
        "|H|))",
    )
    p.add_argument(
        "--t_end", type=positive_float, default=10.0, help="rollout horizon > 0 (default: 10)"
    )
    p.add_argument(
        "--n_points",
        type=integer_at_least(2),
        default=200,
        help="rollout times from 0 to t_end, >= 2 (default: 200)",
    )
    p.add_argument(
        "--starts", type=positive_int, default=4, help="held-out starts to bump (default: 4)"
    )
    p.add_argument(
        "--out",
        type=output_directory,
        default=None,
        help="a directory (default: the checkpoint's run, else the checkpoint's directory)",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """``hnn-pl bump --config X --ckpt_path C [--delta D] …``: bump the held-out
    starts of a trained HNN and write ``bump.pt`` and ``bump.png`` into its run."""
    args = parser().parse_args(argv)
    import torch

    from hnn_pl.bump import bump_and_roll_out
    from hnn_pl.commands.cli import cli_main, print_summary
    from hnn_pl.commands.config_paths import resolve_config
    from hnn_pl.evaluation import view_of
    from hnn_pl.loggers import resolve_checkpoint, run_directory
    from hnn_pl.plotting import bump_figure
    from hnn_pl.safe_io import check_model_class, load_checkpoint, save_atomic

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
    t = torch.linspace(0, args.t_end, args.n_points, dtype=torch.float64)
    delta, before, after = bump_and_roll_out(
        model, held_out[: args.starts], args.delta, t, DELTA_SHARE
    )
    out = args.out or run_directory(args.ckpt_path) or Path(args.ckpt_path).resolve().parent
    out.mkdir(parents=True, exist_ok=True)
    save_atomic(
        {"delta": delta, "before": before.as_dict(), "after": after.as_dict()}, out / "bump.pt"
    )
    bump_figure(before, after, delta, out / "bump.png")
    moved = after.h_pred[0] - before.h_pred[0]
    drift = (after.h_pred - after.h_pred[:1]).abs().max()
    metrics = {"delta": delta, "moved_mean": moved.mean(), "h_drift_max": drift}
    files = {"wrote": f"{out / 'bump.pt'}, {out / 'bump.png'}"}
    print_summary(out, args.ckpt_path, metrics, f"bumped rollout of {args.starts} starts", files)
    return 0
