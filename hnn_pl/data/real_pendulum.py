"""The measured pendulum's data (paper task 3)."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from hnn_pl.data.base import TrajectoryDataModule
from hnn_pl.systems.base import system_spec
from hnn_pl.systems.real_pendulum import RealPendulum, load_real_pendulum


class RealPendulumData(TrajectoryDataModule):
    """Finite differences of the measured trajectory, split as the reference.

    With states ``y_i = (θ_i, θ̇_i)`` at times ``t_i`` (556 samples, mostly
    ``Δt = 1/6``), inputs are ``y_i`` and targets ``(y_{i+1} − y_i)/(t_{i+1} − t_i)``
    with the real gaps: 555 pairs (``differences="forward"``, the paper's). Forward
    differences of an oscillation are biased towards decay: for ``y = e^{iωt}`` they
    give ``(e^{iωΔt} − 1)/Δt``, whose real part ``−(1 − cos ωΔt)/Δt`` reads as friction
    a model with a dissipative term learns. ``differences="central"`` uses
    ``x_i = y_{i+1}``, ``(y_{i+2} − y_i)/(t_{i+2} − t_i)`` (554 pairs, ``i`` indexed as
    before): ``i sin(ωΔt)/Δt``, no spurious decay. Test = pairs ``test_start … test_stop − 1``
    (default 444…553: 110 pairs, ``t`` = 81.0 … 99.17), train = every other pair
    (445). The held-out trajectory for rollouts is the measured segment itself,
    ``test_y (110, 1, 2)`` at ``test_t (110,)``; there is no ground truth beyond
    it. Energy: :class:`~hnn_pl.systems.real_pendulum.RealPendulum` (fitted).

    Args:
        path: a data file of the same format (``None``: the shipped copy).
        test_start, test_stop: the held-out pairs ``[test_start, test_stop)``.
        differences: ``"forward"`` (paper) or ``"central"``.
        batch_size, full_batch_steps, seed, cache_dir, dtype: see :class:`TrajectoryDataModule`.
    """

    def __init__(
        self,
        path: str | None = None,
        test_start: int = 444,
        test_stop: int = 554,
        batch_size: int | None = None,
        full_batch_steps: int = 100,
        seed: int | None = None,
        cache_dir: str | None = None,
        dtype: str = "float32",
        differences: str = "forward",
    ) -> None:
        if differences not in ("forward", "central"):
            raise ValueError(f"differences must be 'forward' or 'central', got {differences!r}")
        super().__init__(batch_size, full_batch_steps, seed, cache_dir, dtype)
        self.save_hyperparameters(ignore=["cache_dir"])
        self.differences = differences
        self.path = path
        self.test_start, self.test_stop = test_start, test_stop
        self.system = RealPendulum()
        self.hparams["system"] = system_spec(self.system)

    @property
    def state_dim(self) -> int:
        return 2

    def cache_params(self) -> dict[str, Any]:
        params = {"path": self.path, "test": [self.test_start, self.test_stop]}
        return params if self.differences == "forward" else {**params, "differences": "central"}

    def generate(self) -> dict[str, Tensor]:
        t, y = load_real_pendulum(self.path)
        if self.differences == "central":
            x, dx = y[1:-1], (y[2:] - y[:-2]) / (t[2:] - t[:-2])[:, None]
            t = t[1:-1]
        else:
            x, dx = y[:-1], (y[1:] - y[:-1]) / (t[1:] - t[:-1])[:, None]
        a, b = self.test_start, self.test_stop
        train = list(range(a)) + list(range(b, len(x)))
        return {
            "x_train": x[train],
            "dx_train": dx[train],
            "x_test": x[a:b],
            "dx_test": dx[a:b],
            "test_t": t[a:b],
            "test_y": x[a:b, None],
        }

    def rollout_target(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """The measured test segment ``(t (110,), y (110, 1, 2))``; a ``t_end`` other than
        ``None`` raises ``ValueError`` (no ground truth beyond the recording)."""
        if t_end is not None:
            raise ValueError("the real pendulum has no ground truth off the recording: t_end: null")
        return self.test_t, self.test_y

    def true_field(self, t: Tensor, y: Tensor) -> Tensor:
        """The measured ``dy/dt`` along a recorded segment ``y (T, B, D)`` at ``t (T,)``:
        second-order central differences with the real gaps (one-sided at the ends,
        ``torch.gradient``); the fitted energy's conservative field would hide the
        friction the recording has."""
        return torch.gradient(y, spacing=(t.to(y.dtype),), dim=0)[0]
