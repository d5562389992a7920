"""Time to accuracy: the training time until a model reaches the paper's accuracy and
the paper recipe's motion (a callback ``reproduce`` and ``benchmarks/`` attach)."""

from __future__ import annotations

import math
import time

from lightning.pytorch import Callback, LightningModule, Trainer

from hnn_pl.evaluation import eval_mode, score, task_protocol
from hnn_pl.experiments import paper


class TimeToAccuracy(Callback):
    """Training time until the model reaches the paper's accuracy *and* the paper
    recipe's motion.

    Every ``every_n_steps`` optimiser steps (rank zero) the model is scored on its
    task's reference protocol, truth prepared once in ``setup`` (state tasks: by
    default batched float64 ``dopri5`` at the protocol's ≈1e-6 accuracy, see
    :meth:`hnn_pl.evaluation.ReferenceCase.run`; pixel: the latent rollout and probe).
    A rollout with a diverged row counts as infinitely far.
    A check passes when all of:

    - the energy MSE on the paper's protocol is ≤ ``target`` (the published HNN value);
    - :func:`hnn_pl.evaluation.motion_error` ≤ ``max_motion_error`` (1 for a model
      that never moves: a still state conserves any energy);
    - the state MSE on the task's clean protocol (without the error floors, truth
      computed once) is ≤ ``state_target``, the paper recipe's median over seeds
      (:attr:`hnn_pl.experiments.paper.PaperTask.paper_motion`). It is computed only
      at checks that pass the first two, until the first pass.

    Logged: ``tta/energy_mse``, ``tta/motion_error``, ``tta/state_mse`` (when
    computed); once passed, ``tta/seconds`` (training time since ``setup``, scoring
    excluded) and ``tta/step``; ``stop`` ends the fit there. Afterwards
    :attr:`reached` is ``{"step", "seconds", "wall_seconds", "energy_mse",
    "motion_error", "state_mse"}`` or ``None``; :attr:`history` every ``(step,
    seconds, energy_mse, motion_error, state_mse)`` (``state_mse`` NaN where not
    computed); :attr:`scoring_seconds` the scoring's own cost.

    Args:
        task: a name in :data:`hnn_pl.experiments.paper.PAPER`.
        target: the energy MSE to reach (``None``: the published HNN value).
        every_n_steps: scoring period in optimiser steps.
        stop: end the fit when the target is reached.
        solver: ``"torch"`` or ``"scipy"`` (the published RK45; slower).
        max_motion_error: the largest motion error that counts (0.25: a model at
            half the true speed; trained models measure 0.001–0.07 on the
            reference protocols, untrained ones ≈ 1).
        state_target: the clean state MSE to reach (``None``: the paper recipe's
            median from the registry; ``math.inf`` or a task without one: no
            state condition).
    """

    def __init__(
        self,
        task: str = "spring",
        target: float | None = None,
        every_n_steps: int = 50,
        stop: bool = False,
        solver: str = "torch",
        max_motion_error: float = 0.25,
        state_target: float | None = None,
    ) -> None:
        super().__init__()
        self.task = paper.get(task)
        if not max_motion_error > 0:
            raise ValueError(f"max_motion_error must be > 0, got {max_motion_error}")
        self.max_motion_error = float(max_motion_error)
        if solver not in ("torch", "scipy"):
            raise ValueError(f"solver must be 'torch' or 'scipy', got {solver!r}")
        if every_n_steps < 1:
            raise ValueError(f"every_n_steps must be >= 1, got {every_n_steps}")
        self.target = self.task.published["hnn"].energy_mse if target is None else float(target)
        if state_target is None:
            motion = self.task.paper_motion
            state_target = math.inf if motion is None else motion.state_mse
        if not state_target > 0:
            raise ValueError(f"state_target must be > 0, got {state_target}")
        self.state_target = float(state_target)
        self.every_n_steps, self.stop, self.solver = every_n_steps, stop, solver
        self.reached: dict[str, float] | None = None
        self.history: list[tuple[int, float, float, float, float]] = []
        self.scoring_seconds = 0.0

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        dm = trainer.datamodule
        dm.setup(stage)
        self._reference = task_protocol(self.task.name, "reference").prepare(dm, self.solver)
        self._clean = task_protocol(self.task.name, "clean").prepare(dm)
        self._next = self.every_n_steps
        self._start = time.perf_counter()
        self.scoring_seconds = 0.0

    def _score(self, model: LightningModule) -> tuple[float, float]:
        r = self._reference(model)
        if r.status is not None and bool((r.status != 0).any()):
            return math.inf, math.inf
        m = score(r)
        return m["energy_mse"], m["motion_error"]

    def on_train_batch_end(self, trainer: Trainer, pl_module: LightningModule, *args) -> None:
        step = trainer.global_step
        if step < self._next or not trainer.is_global_zero:
            return
        self._next = step + self.every_n_steps - step % self.every_n_steps
        t0 = time.perf_counter()
        with eval_mode(pl_module):
            (energy, motion), state = self._score(pl_module), math.nan
            passed = energy <= self.target and motion <= self.max_motion_error
            if passed and self.reached is None and math.isfinite(self.state_target):
                state = score(self._clean(pl_module))["state_mse"]
                passed = state <= self.state_target
        seconds = t0 - self._start - self.scoring_seconds
        self.scoring_seconds += time.perf_counter() - t0
        self.history.append((step, seconds, energy, motion, state))
        metrics = {"tta/energy_mse": energy, "tta/motion_error": motion}
        if not math.isnan(state):
            metrics["tta/state_mse"] = state
        if self.reached is None and passed:
            wall = t0 - self._start
            self.reached = {"step": step, "seconds": seconds, "wall_seconds": wall}
            self.reached.update(energy_mse=energy, motion_error=motion, state_mse=state)
            metrics.update({"tta/seconds": seconds, "tta/step": float(step)})
            trainer.should_stop = trainer.should_stop or self.stop
        for logger in trainer.loggers:
            logger.log_metrics(metrics, step=step)
