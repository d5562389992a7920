"""Resume, checkpoint and model-option faults for the CLI fault table
(``test_faults.CASES``): a fit resumed on other data, options given against the
checkpoint's, a checkpoint whose weights are not finite or of another system, options
that would do nothing. Each is refused in one line before anything is written.

``CASES``: id → (argv, files, what the line must say); ``FILES``: files → the maker of
the case's working directory. The resume cases start from one tiny trajectory-objective
checkpoint (2 steps on the recording ``rec_a.csv``), trained once per test session in a
process of its own (:func:`trained_checkpoint`) and copied into each case's directory.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent

HEADER = "trajectory,time,q,p\n"


def _spring_rows(n_trajectories: int, phase: float) -> str:
    """``n_trajectories`` of 6 samples of ``H = q² + p²`` (``q = r cos(2t + φ)``)."""
    rows = []
    for m in range(n_trajectories):
        r, phi = 0.5 + 0.1 * m, phase + 0.7 * m
        for j in range(6):
            t = 0.1 * j
            rows.append(
                f"{m},{t:.1f},{r * math.cos(2 * t + phi):.6f},{-r * math.sin(2 * t + phi):.6f}"
            )
    return HEADER + "\n".join(rows) + "\n"


RECORDINGS = {
    "rec_a": _spring_rows(4, 0.0),
    "rec_b": _spring_rows(4, 1.0),  # as many samples, other values
    "rec_c": _spring_rows(6, 0.0),  # more samples
}


def _config(name: str) -> str:
    return (
        "data:\n  class_path: hnn_pl.data.RecordingData\n  init_args:\n"
        f"    path: {name}.csv\n    test_fraction: 0.5\n    window: 3\n"
    )


_LOCK = threading.Lock()
_TRAINED: dict[str, object] = {}


def _subprocess(argv: list[str], cwd: Path, env: dict) -> None:
    """``python -m hnn_pl *argv`` in a process of its own, ``env`` added."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), **env}
    cmd = [sys.executable, "-m", "hnn_pl", *argv]
    subprocess.run(cmd, cwd=cwd, env=env, check=True, capture_output=True)


#: how :func:`trained_checkpoint` runs its fit: ``run(argv, cwd, env)``, raising if it
#: fails (the fault table's fixture sets a forked child of its CLI server: no imports)
RUN: Callable[[list[str], Path, dict], None] = _subprocess


def trained_checkpoint() -> bytes:
    """The bytes of ``fit --config spring_traj.yaml --config rec_a.yaml
    --trainer.max_steps=2`` (learned states, one per sample), made once per session in a
    process and a directory of its own (:data:`RUN`)."""
    with _LOCK:
        if "bytes" not in _TRAINED:
            tmp = tempfile.TemporaryDirectory(prefix="fault_resume_")
            _TRAINED["dir"] = tmp  # removed with the session
            cwd = Path(tmp.name)
            _recordings(cwd)
            argv = ["fit", "--config", "spring_traj.yaml", "--config", "rec_a.yaml"]
            argv += ["--trainer.max_steps=2", "--trainer.logger=false"]
            argv += [f"--trainer.default_root_dir={cwd}", "--trainer.enable_progress_bar=false"]
            RUN(argv, cwd, {"HNN_PL_CACHE": str(cwd / "cache")})
            _TRAINED["bytes"] = (cwd / "checkpoints" / "last.ckpt").read_bytes()
        return _TRAINED["bytes"]


def _recordings(tmp: Path) -> None:
    for name, text in RECORDINGS.items():
        (tmp / f"{name}.csv").write_text(text)
        (tmp / f"{name}.yaml").write_text(_config(name))


def _trained(tmp: Path) -> None:
    _recordings(tmp)
    (tmp / "model.ckpt").write_bytes(trained_checkpoint())


def _made(spoil: Callable[[dict], None]) -> Callable[[Path], None]:
    """A maker of ``model.ckpt``: a fresh HNN's checkpoint, as ``fit`` saves one on the
    spring (2-D states), changed by ``spoil``."""

    def make(tmp: Path) -> None:
        from hnn_pl.models import HNN
        from hnn_pl.systems import MassSpring, system_spec

        model = HNN()
        ckpt = {
            "state_dict": model.state_dict(),
            "hyper_parameters": {"_class_path": "hnn_pl.models.HNN", **model.hparams},
            "hnn_pl_model_class": "hnn_pl.models.hnn.HNN",
            "datamodule_hyper_parameters": {"system": system_spec(MassSpring())},
        }
        spoil(ckpt)
        torch.save(ckpt, tmp / "model.ckpt")

    return make


def _nan(ckpt: dict) -> None:
    ckpt["state_dict"]["field.net.hidden.0.weight"].fill_(math.nan)


FILES: dict[str, Callable[[Path], None]] = {
    "trained": _trained,
    "nan-checkpoint": _made(_nan),
    "spring-checkpoint": _made(lambda ckpt: None),
}

TRAJ = ["--config", "spring_traj.yaml"]
RESUME = ["fit", *TRAJ, "--config", "rec_a.yaml", "--ckpt_path", "model.ckpt"]
FAST = ["fit", "--config", "spring_fast.yaml", "--trainer.max_steps=2"]
NAN = "checkpoint model.ckpt: its weights are not finite (field.net.hidden.0.weight: 400 of 400"
DERIVATIVE = "only the trajectory objective uses them, and objective is 'derivative'"

#: id: (argv, files, what the line must say)
CASES = {
    "resume-on-another-recording": (
        ["fit", *TRAJ, "--config", "rec_b.yaml", "--ckpt_path", "model.ckpt"],
        "trained",
        "12 states), but this fit's data is RecordingData rec_b.csv (data ",
    ),
    "resume-on-more-samples": (
        ["fit", *TRAJ, "--config", "rec_c.yaml", "--ckpt_path", "model.ckpt"],
        "trained",
        "checkpoint model.ckpt: its learned states were learned on RecordingData rec_a.csv (data ",
    ),
    "resume-with-another-lr": (
        [*RESUME, "--model.init_args.lr=0.5"],
        "trained",
        "--model.init_args.lr=0.5: checkpoint model.ckpt was trained with lr=0.003, and a run "
        "from a checkpoint keeps the options it was trained with",
    ),
    "resume-with-another-objective": (
        [*RESUME, "--model.init_args.objective=derivative"],
        "trained",
        "--model.init_args.objective=derivative: checkpoint model.ckpt was trained with "
        "objective='trajectory'",
    ),
    "test-with-another-objective": (
        ["test", "--config", "spring_fast.yaml", "--ckpt_path", "model.ckpt"],
        "trained",
        "checkpoint model.ckpt was trained with objective='trajectory' but the config sets "
        "objective: 'derivative': use the config the checkpoint was trained with",
    ),
    "test-nan-checkpoint": (
        ["test", "--config", "spring_fast.yaml", "--ckpt_path", "model.ckpt"],
        "nan-checkpoint",
        NAN,
    ),
    "predict-nan-checkpoint": (
        ["predict", "--config", "spring_fast.yaml", "--ckpt_path", "model.ckpt"],
        "nan-checkpoint",
        NAN,
    ),
    "bump-nan-checkpoint": (
        ["bump", "--config", "spring_fast.yaml", "--ckpt_path", "model.ckpt"],
        "nan-checkpoint",
        NAN,
    ),
    "test-another-system": (
        ["test", "--config", "pendulum_fast.yaml", "--ckpt_path", "model.ckpt"],
        "spring-checkpoint",
        "checkpoint model.ckpt was trained on hnn_pl.systems.mass_spring.MassSpring but the "
        "config's data is hnn_pl.systems.pendulum.Pendulum",
    ),
    "bump-another-system": (
        ["bump", "--config", "pendulum_fast.yaml", "--ckpt_path", "model.ckpt"],
        "spring-checkpoint",
        "checkpoint model.ckpt was trained on hnn_pl.systems.mass_spring.MassSpring but the "
        "config's data is hnn_pl.systems.pendulum.Pendulum",
    ),
    "derivative-learned-states": (
        [*FAST, "--model.init_args.learned_states=sample"],
        "",
        f"model.init_args learned_states='sample': {DERIVATIVE}",
    ),
    "derivative-continuity-weight": (
        [*FAST, "--model.init_args.continuity_weight=10"],
        "",
        "model.init_args continuity_weight=10.0: they act on learned states, and "
        "learned_states is 'none'",
    ),
    "derivative-substeps": (
        [*FAST, "--model.init_args.substeps=4"],
        "",
        f"model.init_args substeps=4: {DERIVATIVE}",
    ),
    "derivative-traj-method": (
        [*FAST, "--model.init_args.traj_method=leapfrog"],
        "",
        f"model.init_args traj_method='leapfrog': {DERIVATIVE}",
    ),
    "derivative-state-weight": (
        [*FAST, "--model.init_args.state_weight=3"],
        "",
        "model.init_args state_weight=3.0: they act on learned states, and learned_states is "
        "'none'",
    ),
    "derivative-keep-fraction": (
        [*FAST, "--data.init_args.keep_fraction=0.5"],
        "",
        "data.init_args.keep_fraction: 0.5 thins only the observed trajectories, which the "
        "derivative objective does not use",
    ),
    "state-weight-inf": (
        ["fit", *TRAJ, "--trainer.max_steps=2", "--model.init_args.state_weight=.inf"],
        "",
        "state_weight must be finite and >= 0: inf",
    ),
}
