"""Make the documentation's figures: ``python examples/figures.py [--steps N] [--out DIR]``.

DIR/bump.png: an energy bump of the mass-spring HNN (``spring_fast.yaml``);
DIR/double_well.png: the double well of examples/double_well.py, HNN against baseline.
DIR defaults to the repository's ``docs/``; N to the configs' own steps (a smaller number
draws the same figures of less trained models, quickly).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import matplotlib
import torch

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from hnn_pl import rollout  # noqa: E402
from hnn_pl.commands.bump import main as bump  # noqa: E402
from hnn_pl.commands.cli import cli_main  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


def fit(config: str, *extra: str, steps: int | None = None):
    args = [f"--config={config}", "--seed_everything=0", "--threads=1"]
    args += [] if steps is None else [f"--trainer.max_steps={steps}"]
    args += ["--trainer.enable_progress_bar=false", "--trainer.logger=false", *extra]
    cli = cli_main(args, run=False, save_config=False)
    cli.trainer.fit(cli.model, cli.datamodule)
    return cli


def bump_figure(out: Path, steps: int | None = None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        fit("spring_fast.yaml", f"--trainer.default_root_dir={tmp}", steps=steps)
        (ckpt,) = Path(tmp).rglob("last.ckpt")
        argv = ["--config", "spring_fast.yaml", "--ckpt_path", str(ckpt), "--delta", "0.5"]
        bump([*argv, "--t_end", "4", "--out", str(out)])


def double_well_figure(out: Path, steps: int | None = None) -> None:
    sys.path.insert(0, str(ROOT / "examples"))
    system = ["--data.init_args.system=double_well.DoubleWell"]
    configs = {"HNN": "spring_fast.yaml", "baseline": "spring_fast_baseline.yaml"}
    quiet = ["--trainer.callbacks=[]", "--trainer.enable_checkpointing=false"]
    models = {
        name: fit(config, *system, *quiet, steps=steps).model for name, config in configs.items()
    }
    from double_well import DoubleWell

    well = DoubleWell()
    y0 = torch.tensor([[1.4, 0.0], [0.3, 0.2], [-0.8, 0.6]], dtype=torch.float64)
    t = torch.linspace(0, 30, 600, dtype=torch.float64)
    truth = well.trajectory(y0, t)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    ax1.plot(truth[:, :, 0], truth[:, :, 1], "k-", lw=1)
    for (name, model), color in zip(models.items(), ("C0", "C3"), strict=True):
        traj = rollout(model, y0, t, energy=well.energy)
        ax1.plot(traj.y_pred[:, :, 0], traj.y_pred[:, :, 1], "--", color=color, lw=1)
        for b in range(y0.shape[0]):
            ax2.plot(t, traj.e_pred[:, b], color=color, label=name if b == 0 else None)
    for b in range(y0.shape[0]):
        ax2.plot(t, well.energy(truth[:, b]), "k-", lw=1, label="truth" if b == 0 else None)
    ax1.set(xlabel="q", ylabel="p", title="double well: truth (black), HNN (blue), baseline (red)")
    ax2.set(xlabel="t", ylabel="H = p²/2 + (q² − 1)²/4", title="energy along each rollout")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(out / "double_well.png", dpi=110)
    plt.close(fig)


def main(steps: int | None = None, out: Path = DOCS) -> list[Path]:
    """Both figures into ``out``, models trained for ``steps`` (default: the configs')."""
    out.mkdir(parents=True, exist_ok=True)
    bump_figure(out, steps)
    double_well_figure(out, steps)
    return [out / "bump.png", out / "double_well.png"]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=None, help="training steps of each model")
    parser.add_argument("--out", type=Path, default=DOCS, help="where the figures go")
    args = parser.parse_args()
    print("wrote " + " and ".join(str(p) for p in main(args.steps, args.out)))
