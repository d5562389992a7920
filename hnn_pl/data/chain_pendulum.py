"""The chain-pendulum benchmark of the constrained-HNN paper (Finzi et al. 2020), re-made.

Facts of its public code, with file and line, in ``docs/chain_pendulum.md``. Each split is
drawn from its own seed (training ``data_seed``, validation ``+ 1``, test ``+ 2``) as the
reference does: ``n_pool`` starts from the benchmark's sampler, each integrated over
``[0, horizon)`` every ``dt`` (100 samples), cut into ``horizon / (dt · chunk_len)`` chunks
of ``chunk_len`` samples of which one per trajectory is kept, drawn after the starts from
the same generator. The first ``n_train`` (of a pool of 10 000) make the training set,
so the 100-chunk set is the first eighth of the 800-chunk one. The test set's rollouts
start at its chunks' first states and run ``horizon`` from there.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from hnn_pl.data.base import TrajectoryDataModule, observed_table, require
from hnn_pl.evaluation.metrics import relative_rollout_error
from hnn_pl.integrate import odeint
from hnn_pl.systems.base import system_spec
from hnn_pl.systems.chain_pendulum import REFERENCE_G, ChainPendulum, VelocityChart

#: the coordinates the data may be served in
COORDINATES = ("canonical", "velocity")
#: the size of the start perturbation of the chaos floor
CHAOS_EPS = 1e-4
#: the scoring integrator's budget of attempted dopri5 steps per test trajectory
SCORE_MAX_STEPS = 10_000


class ChainPendulumData(TrajectoryDataModule):
    """The constrained-HNN chain-pendulum protocol: training chunks, validation chunks,
    test starts and their truth (module docstring).

    Served (after ``setup``), in ``coordinates``:

    - ``window=chunk_len`` (default): training batches are whole chunks,
      ``(y (B, 5, 2n), t (B, 5), index (B, 5))``, one window per chunk, ``t`` the
      chunk's own times on the trajectory it was cut from; validation batches the
      validation chunks alike. ``window=None``: derivative pairs ``(y, dy/dt)`` at the
      chunks' states, the exact field (``(n_chunks · 5, 2n)`` each).
    - ``test_t (100,)``, ``test_y (100, n_test, 2n)``: the test rollouts' truth;
      ``rollout_target()`` returns them (the rollout protocols' starts).

    ``coordinates="canonical"``: ``y = (θ, p)``, ``p = M(θ) θ̇`` the true momenta, and
    ``system`` the :class:`~hnn_pl.systems.ChainPendulum`. ``"velocity"``: ``y = (θ, θ̇)``,
    what the reference serves its angle-coordinate models (a Hamiltonian model must
    learn ``p(θ, θ̇)`` itself), and ``system`` its :class:`VelocityChart`.

    Scores: :meth:`rollout_errors` (a field's per-trajectory error on the test set),
    :meth:`chaos_floor` (the true system's from perturbed starts); the benchmark reports
    their medians.

    Args:
        n_links: links of the chain (2 or 3 in the paper's tables; any ``n ≥ 1``).
        n_train, n_val, n_test: chunks of each split (the paper: 100 or 800, 100, 100).
        n_pool: training starts drawn (the reference's 10 000), of which the first
            ``n_train`` are used.
        chunk_len, dt, horizon: samples per chunk, sampling interval, trajectory length.
        data_seed: seed of the training split (validation ``+ 1``, test ``+ 2``); the
            data do not change with the run's seed (``seed``: training order).
        coordinates: ``"canonical"`` or ``"velocity"``.
        masses, lengths, g: the chain (``None``: the reference's draw).
        **kwargs: :class:`TrajectoryDataModule`'s options (``batch_size``, ``seed``,
            ``dtype``, ``window``, …).
    """

    def __init__(
        self,
        n_links: int = 2,
        n_train: int = 800,
        n_val: int = 100,
        n_test: int = 100,
        n_pool: int = 10_000,
        chunk_len: int = 5,
        dt: float = 0.03,
        horizon: float = 3.0,
        data_seed: int = 0,
        coordinates: str = "canonical",
        masses: tuple[float, ...] | None = None,
        lengths: tuple[float, ...] | None = None,
        g: float = REFERENCE_G,
        window: int | None = 5,
        **kwargs: Any,
    ) -> None:
        super().__init__(window=window, **kwargs)
        require(coordinates in COORDINATES, f"coordinates must be one of {COORDINATES}")
        for name, v in (("n_train", n_train), ("n_val", n_val), ("n_test", n_test)):
            require(v >= 1, f"{name} must be >= 1: {v}")
        require(n_pool >= n_train, f"n_pool ({n_pool}) must be >= n_train ({n_train})")
        require(math.isfinite(dt) and dt > 0, f"dt must be > 0: {dt}")
        n_points = round(horizon / dt)
        require(
            n_points >= 2 and abs(n_points * dt - horizon) < 1e-9 * horizon,
            f"horizon ({horizon}) must be a multiple of dt ({dt})",
        )
        require(
            chunk_len >= 2 and n_points % chunk_len == 0,
            f"chunk_len ({chunk_len}) must be >= 2 and divide the {n_points} samples",
        )
        self.chain = ChainPendulum(n_links, masses, lengths, g)
        self.system = self.chain if coordinates == "canonical" else VelocityChart(self.chain)
        self.hparams["system"] = system_spec(self.chain)
        self.n_links, self.coordinates = n_links, coordinates
        self.n_train, self.n_val, self.n_test, self.n_pool = n_train, n_val, n_test, n_pool
        self.chunk_len, self.dt, self.horizon, self.n_points = chunk_len, dt, horizon, n_points
        self.data_seed = data_seed
        self._float64: dict[str, Tensor] | None = None

    @property
    def state_dim(self) -> int:
        return 2 * self.n_links

    def cache_params(self) -> dict[str, Any]:
        names = ("n_train", "n_val", "n_test", "n_pool", "chunk_len", "dt", "horizon")
        return {
            "system": system_spec(self.chain),
            **{name: getattr(self, name) for name in names},
            "data_seed": self.data_seed,
            "coordinates": self.coordinates,
            "chain_version": 1,
        }

    def times(self) -> Tensor:
        """The sample times ``k · dt``, ``k = 0 … n_points − 1``: ``(T,)`` float64."""
        return torch.arange(self.n_points, dtype=torch.float64) * self.dt

    def _split(self, seed: int, pool: int, m: int) -> tuple[Tensor, Tensor]:
        """``m`` chunks of a split: the chosen chunks ``(m, K, 2n)`` (canonical) and
        their sample indices on the trajectory grid ``(m, K)``."""
        g = torch.Generator().manual_seed(seed)
        y0 = self.chain.sample_initial(pool, g)[:m]
        n_chunks = self.n_points // self.chunk_len
        chunk = torch.randint(0, n_chunks, (pool,), generator=g)[:m]
        y = self.chain.trajectory(y0, self.times())
        rows = chunk[:, None] * self.chunk_len + torch.arange(self.chunk_len)
        return y[rows, torch.arange(m)[:, None]], rows

    def generate(self) -> dict[str, Tensor]:
        t = self.times()
        served = (lambda y: y) if self.coordinates == "canonical" else self.system.from_canonical
        train, train_rows = self._split(self.data_seed, self.n_pool, self.n_train)
        val, val_rows = self._split(self.data_seed + 1, self.n_val, self.n_val)
        test, _ = self._split(self.data_seed + 2, self.n_test, self.n_test)
        test_y = served(self.chain.trajectory(test[:, 0], t))
        data = {"test_t": t, "test_y": test_y}
        for split, chunks, rows in (("train", train, train_rows), ("test", val, val_rows)):
            y = served(chunks)
            data[f"x_{split}"] = y.reshape(-1, self.state_dim)
            data[f"dx_{split}"] = self.system.vector_field(None, data[f"x_{split}"])
            data[f"obs_y_{split}"], _, data[f"obs_traj_{split}"] = observed_table(
                y.transpose(0, 1), t[: self.chunk_len]
            )
            data[f"obs_t_{split}"] = t[rows].reshape(-1)
        return data

    def load_data(self) -> dict[str, Tensor]:
        data = super().load_data()
        self._float64 = data
        return data

    def truth(self) -> tuple[Tensor, Tensor]:
        """The test rollouts' float64 truth: ``t (T,)`` and ``y (T, n_test, 2n)``."""
        data = self._float64 if self._float64 is not None else self.load_data()
        return data["test_t"], data["test_y"]

    def cartesian(self, y: Tensor) -> Tensor:
        """States in the served coordinates ``(..., 2n)`` as the reference's Cartesian
        state, bob positions and velocities ``(..., 2, n, 2)``."""
        q, w = y.chunk(2, dim=-1)
        v = self.chain.velocity(q, w) if self.coordinates == "canonical" else w
        return self.chain.cartesian_qv(q, v)

    def rollout_errors(
        self,
        field: Any,
        rtol: float = 1e-7,
        atol: float = 1e-9,
        denominator: str = "sum_of_norms",
        max_steps: int = SCORE_MAX_STEPS,
    ) -> Tensor:
        """The benchmark's error of a field on the test set, per trajectory ``(n_test,)``.

        ``field``: ``f(t, y)`` on batches of served states ``(B, 2n)``, or a model or
        anything with ``vector_field`` (then evaluated in float64,
        :func:`~hnn_pl.evaluation.observer.float64_field`). Integrated in float64 from
        the test starts with ``dopri5`` at ``rtol``, ``atol`` (the reference's ``tol``
        1e-7; ``atol`` its solver's default 1e-9) to the ``T`` test times, mapped to
        Cartesian positions and velocities and scored by
        :func:`~hnn_pl.evaluation.metrics.relative_rollout_error` (geometric mean over
        time, horizon 3 s); a row that stopped counts as error 1 from there, among them
        a row that needs more than ``max_steps`` attempted steps (the true field's slowest
        of the 100 test trajectories takes 210: a learned field whose steps shrink without
        end, as a near-singular Lagrangian's can, is scored in bounded time instead of for
        hours)."""
        from hnn_pl.evaluation.observer import float64_field

        if hasattr(field, "vector_field") or hasattr(field, "field"):
            field = float64_field(field)[0]
        t, y_true = self.truth()
        sol = odeint(
            field,
            y_true[0],
            t,
            "dopri5",
            rtol=rtol,
            atol=atol,
            options={"max_steps": max_steps},
            return_status=True,
        )
        return self._score(sol.y, y_true, denominator)

    def chaos_floor(
        self, eps: float = CHAOS_EPS, seed: int = 0, denominator: str = "sum_of_norms"
    ) -> Tensor:
        """The true system's error from starts perturbed as the reference does, per
        trajectory ``(n_test,)``: each test start's Cartesian state plus
        ``eps · N(0, 1)`` on every coordinate (a draw seeded ``seed``), projected back
        onto the constraints (:meth:`ChainPendulum.project`), integrated at the truth's
        tolerance and scored as :meth:`rollout_errors`."""
        t, y_true = self.truth()
        z0 = self.cartesian(y_true[0])
        g = torch.Generator().manual_seed(seed)
        z0 = z0 + eps * torch.randn(z0.shape, generator=g, dtype=torch.float64)
        y0 = self.chain.from_cartesian(z0)
        y = self.chain.trajectory(y0, t)
        if self.coordinates == "velocity":
            y = self.system.from_canonical(y)
        return self._score(y, y_true, denominator)

    def _score(self, y_pred: Tensor, y_true: Tensor, denominator: str) -> Tensor:
        z_pred = self.cartesian(y_pred.transpose(0, 1).to(torch.float64))
        z_true = self.cartesian(y_true.transpose(0, 1))
        return relative_rollout_error(z_pred, z_true, self.dt, self.horizon, denominator)
