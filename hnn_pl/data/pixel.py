"""Data of the pixel pendulum (paper task 5): pairs of rendered gym frames.

Trajectories of gym's Pendulum-v0 without torque (:class:`~hnn_pl.systems.
pixel_pendulum.PixelPendulum`), drawn at 28 × 28 by :func:`hnn_pl.render.
render_pendulum`; an input is two consecutive frames, flattened row-major and
concatenated (earlier frame first): ``2·28² = 1568`` values.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import torch
from torch import Tensor

from hnn_pl.data.base import TrajectoryDataModule, split_sizes
from hnn_pl.systems.base import system_spec
from hnn_pl.systems.pixel_pendulum import PixelPendulum


class PixelPendulumData(TrajectoryDataModule):
    """Pairs of consecutive frames of gym pendulum trajectories, as the reference.

    **Generation** (cached, float64, seeded by ``seed``): ``n_trajectories`` starts
    ``θ₀ ~ U(−max_angle, max_angle)``, ``θ̇₀ ~ U(−max_omega, max_omega)``, stepped by
    gym's semi-implicit Euler (``g``, ``dt``) to ``n_frames`` frames. The first
    ``n_test = round(test_fraction · n_trajectories)`` are held out (as the reference's
    first 20 % of samples) and continued to ``max(n_frames, rollout_frames + 1)``
    frames for the rollouts. Only ``θ, θ̇`` are cached: rendering the frames in
    ``setup`` (≈ 3 s) beats loading ≈ 180 MB and never goes stale.

    **Samples** (the reference's ``make_gym_dataset``): with ``P_k`` the pair (frame
    ``k``, frame ``k + 1``), each trajectory gives ``n_frames − 3`` inputs
    ``P_1 … P_{n−3}`` (the reference drops ``P_0``) and their successors
    ``P_2 … P_{n−2}``, ordered by trajectory, then time. A pair's state is the true
    ``(θ, θ̇)`` of its *second* frame (for gym's ``θ_{k+1} = θ_k + θ̇_{k+1}·dt`` the
    pair shows exactly that velocity; the reference's label one step later is not
    reproduced). After ``setup`` (served dtype):

    - ``x_train (N_train, 1568)``: inputs ``P_k``; ``dx_train``: the **next input**
      ``P_{k+1}`` (not a derivative); ``y_train (N_train, 2)``: ``(θ, θ̇)``.
      Defaults: 16 000 train rows, 4 000 test rows (``x_test, dx_test, y_test``).
    - ``test_t (R,)``: ``k·dt``, ``R = rollout_frames``; ``test_y (R, n_test, 2)``:
      the states of ``P_k``; ``rollout_x (R, n_test, 1568)``: the pairs ``P_k``.
    - ``theta, omega, rollout_theta, rollout_omega``: the cached float64 trajectories.

    Batches are ``(x, x_next)``. :meth:`energy` takes ``(θ, θ̇)`` states:
    ``α(1 − cos θ) + (c·θ̇)²`` in the reference's coordinates ``(q, p) = (θ, c·θ̇)``.

    Args:
        n_trajectories: number of trajectories (200).
        n_frames: frames per trajectory (103).
        rollout_frames: rollout length in pairs (200).
        test_fraction: share of the trajectories held out (the first ones).
        size: frame side in pixels (28).
        render_filter, supersample, arrow: passed to :func:`~hnn_pl.render.render_pendulum`;
            the defaults (tent, 4, the torque arrow's band) reproduce the frames of
            gym 0.12.1's own renderer (mean absolute difference 0.0005); ``"box", 1,
            False`` is the plain scene drawn ~10 × faster (0.0046 from the reference's).
        dt, g: gym's step and gravity.
        max_angle, max_omega: bounds of ``|θ₀|`` and ``|θ̇₀|``.
        momentum_scale: ``c`` in ``p = c·θ̇`` (0.25).
        energy_coef: ``α`` (``None``: ``3gc²/l = 1.875``; the reference's evaluation
            used the fitted 1.9). Not part of the cache key.
        batch_size: training rows per step (200).
        full_batch_steps, seed, cache_dir, dtype: see :class:`TrajectoryDataModule`.
    """

    def __init__(
        self,
        n_trajectories: int = 200,
        n_frames: int = 103,
        rollout_frames: int = 200,
        test_fraction: float = 0.2,
        size: int = 28,
        render_filter: str = "tent",
        supersample: int = 4,
        arrow: bool = True,
        dt: float = 0.05,
        g: float = 10.0,
        max_angle: float = math.pi / 6,
        max_omega: float = 1.0,
        momentum_scale: float = 0.25,
        energy_coef: float | None = None,
        batch_size: int | None = 200,
        full_batch_steps: int = 100,
        seed: int | None = None,
        cache_dir: str | None = None,
        dtype: str = "float32",
    ) -> None:
        super().__init__(batch_size, full_batch_steps, seed, cache_dir, dtype)
        for name in ("window", "keep_fraction", "observe"):  # frames: no observed trajectories
            self.hparams.pop(name, None)
        if n_frames < 4:
            raise ValueError(f"n_frames must be >= 4 (one sample needs 4 frames), got {n_frames}")
        if rollout_frames < 1:
            raise ValueError(f"rollout_frames must be >= 1, got {rollout_frames}")
        self.n_test = split_sizes(n_trajectories, test_fraction)
        self.n_trajectories, self.n_frames = n_trajectories, n_frames
        self.rollout_frames, self.test_fraction = rollout_frames, test_fraction
        self.size, self.render_filter, self.supersample = size, render_filter, supersample
        self.arrow = arrow
        keys = ("dt", "g", "momentum_scale", "energy_coef", "max_angle", "max_omega")
        self.system = PixelPendulum(**{k: self.hparams[k] for k in keys})
        self.hparams["system"] = system_spec(self.system)

    @property
    def state_dim(self) -> int:
        """``2·size²``: the length of an input (two flattened frames), 1568."""
        return 2 * self.size**2

    def cache_params(self) -> dict[str, Any]:
        s = self.system
        return {
            "n_trajectories": self.n_trajectories,
            "n_frames": self.n_frames,
            "rollout_frames": self.rollout_frames,
            "test_fraction": self.test_fraction,
            "dynamics": [s.dt, s.g, s.l, s.m, s.max_speed],
            "start": [s.max_angle, s.max_omega],
            "seed": self.seed,
        }

    def generate(self) -> dict[str, Tensor]:
        theta0, omega0 = self.system.sample_initial(self.n_trajectories, self._generator())
        k, n, r = self.n_test, self.n_frames, self.rollout_frames + 1
        th_test, om_test = self.system.simulate(theta0[:k], omega0[:k], max(n, r) - 1)
        th_train, om_train = self.system.simulate(theta0[k:], omega0[k:], n - 1)
        return {
            "theta": torch.cat([th_test[:, :n], th_train]),
            "omega": torch.cat([om_test[:, :n], om_train]),
            "rollout_theta": th_test[:, :r],
            "rollout_omega": om_test[:, :r],
        }

    def render(self, theta: Tensor) -> Tensor:
        """Frames of angles ``(...)``, flattened: ``(..., size²)``, rendered in float32
        (so the served frames do not depend on the served dtype; 3 × faster than
        float64, and 1e-7 is far below the frames' own 8-bit steps) and returned in it."""
        kwargs = dict(filter=self.render_filter, supersample=self.supersample, arrow=self.arrow)
        return self.system.render(theta.float(), self.size, **kwargs).flatten(-2).to(self.dtype)

    @staticmethod
    def pairs(frames: Tensor) -> Tensor:
        """``(..., F, size²) -> (..., F − 1, 2·size²)``: pair ``k`` = frames ``k, k + 1``."""
        return torch.cat([frames[..., :-1, :], frames[..., 1:, :]], dim=-1)

    def setup(self, stage: str | None = None) -> None:
        """Load (or generate) the trajectories, render them and form the samples."""
        if self.data is not None:
            return
        d = self.load_data()  # float64: render from exact θ
        state = torch.stack([d["theta"], d["omega"]], -1).to(self.dtype)  # (N, F, 2)
        p = self.pairs(self.render(d["theta"]))  # (N, F - 1, 1568)
        x, nx, y = p[:, 1:-1], p[:, 2:], state[:, 2:-1]  # P_k, P_{k+1}, state of frame k + 1
        served = {
            f"{name}_{split}": a[sel].reshape(-1, a.shape[-1])
            for split, sel in (("train", slice(self.n_test, None)), ("test", slice(self.n_test)))
            for name, a in (("x", x), ("dx", nx), ("y", y))
        }
        truth = self._rollout_truth(d["rollout_theta"], d["rollout_omega"], self.rollout_frames)
        served.update(zip(("test_t", "test_y", "rollout_x"), truth))
        self.data = {**d, **served}  # the trajectories stay float64 (for extensions)
        for key, value in self.data.items():
            setattr(self, key, value)

    def _rollout_truth(self, theta: Tensor, omega: Tensor, n: int) -> tuple[Tensor, Tensor, Tensor]:
        """``t (n,)``, ``y (n, B, 2)`` and pairs ``(n, B, 1568)`` of trajectories
        ``(B, ≥ n + 1)``, time first."""
        t = torch.arange(n, dtype=torch.float64) * self.system.dt
        y = torch.stack([theta[:, 1 : n + 1], omega[:, 1 : n + 1]], -1).transpose(0, 1)
        x = self.pairs(self.render(theta[:, : n + 1])).transpose(0, 1)
        return t.to(self.dtype), y.to(self.dtype), x.contiguous()

    def canonical(self, y: Tensor) -> Tensor:
        """``(θ, θ̇) (..., 2) -> (q, p) = (θ, c·θ̇) (..., 2)``."""
        return self.system.to_canonical(y[..., 0], y[..., 1])

    def energy(self, y: Tensor) -> Tensor:
        """``α(1 − cos θ) + (c·θ̇)²`` of ``(θ, θ̇)`` states ``(..., 2) -> (...)``."""
        return self.canonical_energy(self.canonical(y))

    def canonical_energy(self, qp: Tensor, energy_coef: float | None = None) -> Tensor:
        """``α(1 − cos q) + p²`` of canonical ``(q, p)`` states ``(..., 2) -> (...)``,
        ``α = energy_coef`` (``None``: the system's)."""
        if energy_coef is None:
            return self.system.energy(qp)
        system = copy.copy(self.system)
        system.energy_coef = energy_coef
        return system.energy(qp)

    def probe_data(self, n: int | None = None) -> tuple[Tensor, Tensor]:
        """The first ``n`` training inputs ``(n, 1568)`` and their canonical ``(q, p)
        (n, 2)``: what a linear probe ``z ↦ (q, p)`` is fitted on."""
        self.setup()
        return self.x_train[:n], self.canonical(self.y_train[:n])

    def rollout_truth(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """``t (T,)``, ``(θ, θ̇) (T, B, 2)`` and pairs ``(T, B, 1568)`` of the held-out
        trajectories, ``B = n_test``, on the frame grid: ``T = n_points`` if given, else
        ``floor(t_end/dt) + 1``, else ``rollout_frames``. Longer than stored: simulated
        from the same starts and rendered (once per length, kept)."""
        if n_points is not None:
            n = int(n_points)
        elif t_end is not None:
            n = int(math.floor(t_end / self.system.dt + 1e-9)) + 1
        else:
            n = self.rollout_frames
        if n < 1:
            raise ValueError(f"a rollout needs at least one point, got {n}")
        if n <= self.rollout_frames:
            return self.test_t[:n], self.test_y[:n], self.rollout_x[:n]
        key = ("pixel", n)
        if key not in self._rollout_cache:
            th0, om0 = self.rollout_theta[:, 0], self.rollout_omega[:, 0]
            self._rollout_cache[key] = self._rollout_truth(*self.system.simulate(th0, om0, n), n)
        return self._rollout_cache[key]

    def trajectory_truth(
        self, theta0: float, omega0: float, n: int
    ) -> tuple[Tensor, Tensor, Tensor]:
        """``t (n,)``, ``(θ, θ̇) (n, 1, 2)`` and pairs ``(n, 1, 1568)`` of one fresh
        trajectory from ``(θ₀, θ̇₀)`` (kept once made): ``n + 2`` frames with the first
        dropped, as the reference's ``make_gym_dataset`` made its test trajectory (pair
        ``k`` = frames ``k + 1, k + 2``, the state of frame ``k + 2``)."""
        key = ("start", float(theta0), float(omega0), int(n))
        if key not in self._rollout_cache:
            start = torch.tensor([[theta0, omega0]], dtype=torch.float64)
            theta, omega = self.system.simulate(start[:, 0], start[:, 1], n + 1)
            self._rollout_cache[key] = self._rollout_truth(theta[:, 1:], omega[:, 1:], n)
        return self._rollout_cache[key]

    def rollout_target(
        self, t_end: float | None = None, n_points: int | None = None
    ) -> tuple[Tensor, Tensor]:
        """``t (T,)`` and the true ``(θ, θ̇) (T, B, 2)``: see :meth:`rollout_truth`
        (whose third output, the true frame pairs, the pixel callback also uses)."""
        return self.rollout_truth(t_end, n_points)[:2]
