"""Data of a simulated Hamiltonian system (mass-spring, pendulum, n-body)."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from hnn_pl.data.base import TrajectoryDataModule, observed_table, require, split_sizes
from hnn_pl.safe_io import require_memory
from hnn_pl.systems.base import HamiltonianSystem, check_system, source_digest, system_spec

#: bytes per state value while a data set is made: float64 trajectories, targets,
#: noisy inputs, their splits, the integrator's output buffers and the served copy
_BYTES_PER_VALUE = 8 * 9


class SimulatedData(TrajectoryDataModule):
    """Trajectories of ``system``, as the reference code makes them.

    ``n_trajectories`` initial states from ``system.sample_initial``; each integrated
    in float64 (closed form, or batched per-trajectory adaptive ``dopri5``) to
    ``n_points`` equally spaced times on ``t_span``. Targets are the analytic
    ``dy/dt = J∇H`` at the clean states; inputs are the clean states plus
    ``N(0, noise_std²)`` noise on every coordinate. The split is by trajectory: a
    ``test_fraction`` of them, the first ones if ``test_first`` (two-/three-body
    reference) else the last ones (spring/pendulum reference).

    Checked when built, before anything is written: a data set whose estimated
    memory exceeds the machine's, and a system whose sampler or ``H`` is wrong on the
    data's own starts (:func:`~hnn_pl.systems.base.check_system`), are refused in one
    line. The cache key covers the source of a system defined outside this package.

    The same noisy states, split alike, are the observed trajectories (``obs_*``
    tables, and with ``window`` the loaders' windows): the paper's draws with the
    derivatives withheld.

    Args:
        system: the physical system (``class_path`` in YAML).
        n_trajectories: number of trajectories.
        t_span: ``(t₀, t₁)`` of each trajectory.
        n_points: samples per trajectory.
        noise_std: standard deviation of the input noise.
        test_fraction: share of the trajectories held out.
        test_first: hold out the first (not the last) trajectories.
        **kwargs: the data options of :class:`TrajectoryDataModule` (``batch_size``,
            ``seed``, ``dtype``, ``window``, ``observe``, …).
    """

    def __init__(
        self,
        system: HamiltonianSystem,
        n_trajectories: int = 50,
        t_span: tuple[float, float] = (0.0, 3.0),
        n_points: int = 30,
        noise_std: float = 0.1,
        test_fraction: float = 0.5,
        test_first: bool = False,
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        split_sizes(n_trajectories, test_fraction)
        require(n_points >= 2, f"n_points must be >= 2: {n_points}")
        t0, t1 = (float(t) for t in t_span)
        require(math.isfinite(t0) and math.isfinite(t1) and t1 > t0, f"bad t_span {t_span}")
        require(math.isfinite(noise_std) and noise_std >= 0, f"noise_std must be >= 0: {noise_std}")
        self.system = system
        self.hparams["system"] = system_spec(system)
        self.n_trajectories, self.n_points, self.noise_std = n_trajectories, n_points, noise_std
        self.t_span = tuple(float(t) for t in t_span)
        self.test_fraction, self.test_first = test_fraction, test_first
        require_memory(
            _BYTES_PER_VALUE * n_trajectories * n_points * system.state_dim,
            f"a data set of {n_trajectories:,} trajectories × {n_points} points",
        )
        check_system(system, system.sample_initial(n_trajectories, self._generator()))

    @property
    def state_dim(self) -> int:
        return self.system.state_dim

    def cache_params(self) -> dict[str, Any]:
        names = ("n_trajectories", "t_span", "n_points", "noise_std", "test_fraction", "test_first")
        params = {name: getattr(self, name) for name in (*names, "seed")}
        source = source_digest(type(self.system))
        return {
            "system": system_spec(self.system),
            **params,
            **({"source": source} if source else {}),
            "observed": 1,
        }

    def generate(self) -> dict[str, Tensor]:
        g = self._generator()
        y0 = self.system.sample_initial(self.n_trajectories, g)
        t = torch.linspace(*self.t_span, self.n_points, dtype=torch.float64)
        y = self.system.trajectory(y0, t)
        dy = self.system.vector_field(t, y)
        x = y + self.noise_std * torch.randn(y.shape, generator=g, dtype=torch.float64)
        n_test = round(self.test_fraction * self.n_trajectories)
        ids = torch.arange(self.n_trajectories)
        test = ids < n_test if self.test_first else ids >= self.n_trajectories - n_test

        def rows(a: Tensor, mask: Tensor) -> Tensor:
            return a[:, mask].transpose(0, 1).reshape(-1, a.shape[-1])

        data = {
            "x_train": rows(x, ~test),
            "dx_train": rows(dy, ~test),
            "x_test": rows(x, test),
            "dx_test": rows(dy, test),
            "test_t": t,
            "test_y": y[:, test],
        }
        for split, mask in (("train", ~test), ("test", test)):
            table = observed_table(x[:, mask], t)
            data.update({f"obs_{k}_{split}": v for k, v in zip(("y", "t", "traj"), table)})
        return data
