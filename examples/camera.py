"""Learn a pendulum from a camera's angles alone: ``python examples/camera.py [STEPS] [DIR]``.

Writes ``DIR/angles.csv`` (default: a new temporary folder): 12 swings of the pendulum
``H = 3(1 − cos q) + p²`` as a tracker would report them — the angle ``q`` only, at
uneven times, noise σ = 0.05, no velocities — and ``DIR/camera.yaml``, the complete
config below, then runs ``hnn-pl fit`` and ``hnn-pl test`` on it. The momenta are
learned; the held-out swings are scored from starts inferred from their first 15 angles.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from hnn_pl.systems import Pendulum

CONFIG = """\
# A pendulum seen by a camera: angles alone (trajectory,time,q). The momenta are learned.
seed_everything: 0
trainer:
  max_steps: {steps}
  default_root_dir: {root}
  logger: {{init_args: {{name: camera_hnn, save_dir: {root}/lightning_logs}}}}
  callbacks:
    - {{class_path: hnn_pl.callbacks.RolloutCallback, init_args: {{task: real_pendulum}}}}
model:
  class_path: hnn_pl.models.HNN
  init_args: {{objective: trajectory, learned_states: sample, continuity_weight: 10.0,
    lr: 3.0e-3, schedule: onecycle}}
data:
  class_path: hnn_pl.data.RecordingData
  init_args: {{path: {root}/angles.csv, system: {{class_path: hnn_pl.systems.Pendulum}},
    test_fraction: 0.25, window: 10, batch_size: 16}}
"""


def write_angles(path: Path, n: int = 12, seed: int = 0) -> None:
    """``n`` swings of 40 samples at uneven times over 3 s, angles only, σ = 0.05."""
    rng, system, rows = np.random.default_rng(seed), Pendulum(), []
    for i in range(n):
        t = np.sort(rng.uniform(0.0, 3.0, 40))
        y0 = torch.tensor([[rng.uniform(-1.5, 1.5), rng.uniform(-1.0, 1.0)]], dtype=torch.float64)
        q = system.trajectory(y0, torch.from_numpy(t))[:, 0, 0].numpy()
        rows.append(np.column_stack([np.full(40, i), t, q + 0.05 * rng.standard_normal(40)]))
    np.savetxt(
        path,
        np.concatenate(rows),
        fmt=["%d", "%.6f", "%.6f"],
        delimiter=",",
        header="trajectory,time,q",
        comments="",
    )


def main(steps: int = 600, folder: str | None = None) -> Path:
    """Write the recording and the config into ``folder``, fit and test; the config's path."""
    from hnn_pl.commands.main import main as hnn_pl

    root = Path(folder or tempfile.mkdtemp(prefix="camera-"))
    root.mkdir(parents=True, exist_ok=True)
    write_angles(root / "angles.csv")
    config = root / "camera.yaml"
    config.write_text(CONFIG.format(steps=steps, root=root))
    for command in ("fit", "test"):
        args = [command, "--config", str(config), "--threads", "1"]
        if command == "test":
            args += ["--ckpt_path", str(root / "lightning_logs" / "camera_hnn")]
        hnn_pl(args)  # exits with status 2 and one line on a refusal
    return config


if __name__ == "__main__":
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 600
    print(f"config and run: {main(steps, sys.argv[2] if len(sys.argv) > 2 else None).parent}")
