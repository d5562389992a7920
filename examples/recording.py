"""Learn from your own recording: ``python examples/recording.py [STEPS] [DIR]`` (seconds,
one core).

Writes ``DIR/springs.csv`` (default: a new temporary folder): 8 noisy mass-spring orbits,
each sampled at its own uneven times, no derivatives. Trains an HNN on windows of its
states and rolls it out from the first sample of each held-out orbit. Prints the held-out
errors beside those of the true system's own rollout from the same noisy starts (the floor
the noise sets).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import lightning as L
import numpy as np
import torch

from hnn_pl import HNN, Protocol, RecordingData
from hnn_pl.commands.cli import QUIET_TRAINER
from hnn_pl.evaluation import evaluate
from hnn_pl.loggers import quiet_lines
from hnn_pl.systems import MassSpring


def write_recording(path: str, n: int = 8, seed: int = 0) -> None:
    """``n`` orbits of ``H = q² + p²`` (``q = r cos(2t + φ)``, ``p = −r sin(2t + φ)``),
    40 samples each at uneven times, noise σ = 0.05."""
    rng, rows = np.random.default_rng(seed), []
    for i in range(n):
        t = np.sort(rng.uniform(0.0, 3.0, 40))
        r, phi = rng.uniform(0.3, 1.0), rng.uniform(0.0, 2 * np.pi)
        q, p = r * np.cos(2 * t + phi), -r * np.sin(2 * t + phi)
        y = np.stack([q, p], 1) + 0.05 * rng.standard_normal((40, 2))
        rows.append(np.column_stack([np.full(40, i), t, y]))
    np.savetxt(
        path, np.concatenate(rows), delimiter=",", header="trajectory,time,q1,p1", comments=""
    )


def main(steps: int = 200, folder: str | None = None) -> dict[str, float]:
    """Write the recording into ``folder`` (default: a new temporary folder), train for
    ``steps`` steps and score the held-out rollouts: the metrics of
    :func:`hnn_pl.evaluation.evaluate`."""
    quiet_lines()
    torch.set_num_threads(1)
    L.seed_everything(0, verbose=False)
    root = Path(folder or tempfile.mkdtemp(prefix="recording-"))
    root.mkdir(parents=True, exist_ok=True)
    path = str(root / "springs.csv")
    write_recording(path)
    dm = RecordingData(path, system=MassSpring(), test_fraction=0.25, window=4)
    model = HNN(input_dim=2, hidden_dim=64, lr=1e-2, schedule="onecycle", objective="trajectory")
    trainer = L.Trainer(max_steps=steps, **QUIET_TRAINER)
    trainer.fit(model, dm)
    metrics, _ = evaluate(model, dm, Protocol(t_end=None, n_points=None))
    return metrics


if __name__ == "__main__":
    m = main(int(sys.argv[1]) if len(sys.argv) > 1 else 200, *sys.argv[2:3])
    print(f"held-out rollouts: state MSE {m['state_mse']:.2e}, energy MSE {m['energy_mse']:.2e}")
    print(
        f"true system from the same starts: state MSE {m['floor_integrator_state_mse']:.2e}, "
        f"energy MSE {m['floor_integrator_energy_mse']:.2e}"
    )
