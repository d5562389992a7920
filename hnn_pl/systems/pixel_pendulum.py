"""Pixel pendulum (paper task 5): gym Pendulum-v0's dynamics, batched, and its energy.

The reference (``experiment-pixels/data.py``) steps gym's ``Pendulum-v0`` with zero
torque (``gym/envs/classic_control/pendulum.py`` of that era)::

    newthdot = thdot + (-3*g/(2*l) * np.sin(th + np.pi) + 3./(m*l**2)*u) * dt
    newth = th + newthdot*dt
    newthdot = np.clip(newthdot, -self.max_speed, self.max_speed)   # max_speed = 8

with ``th = 0`` upright, ``g = 10``, ``m = l = 1``, ``dt = 0.05``; ``reset`` draws
``(th, thdot) ~ U([−π, π] × [−1, 1])``. The reference's ``get_theta`` turns the
observation into ``θ = th − π`` wrapped into ``(−π, π]`` (0 hanging down, same sense of
rotation; ``θ > 0``: rod to the image's right, see :func:`hnn_pl.render.render_pendulum`).
This module uses that ``θ``, in which gym's ``sin(th + π)`` is ``sin θ``. ``PixelPendulum``
is not a :class:`~hnn_pl.systems.base.HamiltonianSystem`: its ground truth is a
fixed-step map, not an ODE integrated to tolerance, and its observations are frames.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hnn_pl.render import render_pendulum


def _wrap(theta: Tensor) -> Tensor:
    """Angles into ``[−π, π)`` (gym's ``angle_normalize``)."""
    return torch.remainder(theta + math.pi, 2 * math.pi) - math.pi


def simulate_gym_pendulum(
    theta0: Tensor | float,
    omega0: Tensor | float,
    n_steps: int,
    dt: float = 0.05,
    g: float = 10.0,
    l: float = 1.0,
    m: float = 1.0,
    *,
    max_speed: float = 8.0,
    torque: float = 0.0,
    max_torque: float = 2.0,
    wrap: bool = False,
) -> tuple[Tensor, Tensor]:
    """Gym Pendulum-v0's semi-implicit Euler, batched over any shape of starts.

    Per step, in gym's order (``θ = 0`` hanging, ``u = clip(torque, ±max_torque)``):
    ``ω' = ω + (−(3g/2l)·sin θ + 3/(m l²)·u)·dt``, ``θ' = θ + ω'·dt`` (the *unclipped*
    ``ω'``), then ``ω' ← clip(ω', ±max_speed)`` (Pendulum-v1 clips first: the same while
    ``|ω| ≤ max_speed``, always here, ``|ω| < 2.5``). Gym never normalises its angle, so
    by default neither does this; ``wrap=True`` returns ``θ`` in ``[−π, π)`` like the
    reference's ``get_theta`` (``(−π, π]``: the same unless the pendulum turns over).

    Args:
        theta0: initial angles, shape ``(...)``.
        omega0: initial angular velocities ``θ̇``, broadcastable with ``theta0``.
        n_steps: number of steps.
        dt, g, l, m: gym's constants.
        max_speed, max_torque: gym's clips of ``ω`` (8) and ``u`` (2).
        torque: constant torque ``u`` (the task uses 0).
        wrap: normalise the returned angles into ``[−π, π)``.

    Returns:
        ``(theta, omega)``, each of shape ``(..., n_steps + 1)`` with the starts at
        index 0, in the floating dtype of the tensor inputs (float64 if there is none;
        Python numbers do not lower it to the default dtype).
    """
    floats = [x.dtype for x in (theta0, omega0) if torch.is_tensor(x) and x.is_floating_point()]
    dtype = torch.promote_types(*floats) if len(floats) == 2 else (floats or [torch.float64])[0]
    th, om = torch.broadcast_tensors(
        torch.as_tensor(theta0, dtype=dtype), torch.as_tensor(omega0, dtype=dtype)
    )
    k = 3 * g / (2 * l)
    drive = 3 / (m * l**2) * max(-max_torque, min(max_torque, torque))
    thetas, omegas = [th], [om]
    for _ in range(n_steps):
        om = om + (-k * torch.sin(th) + drive) * dt
        th = th + om * dt
        om = om.clamp(-max_speed, max_speed)
        thetas.append(th)
        omegas.append(om)
    theta, omega = torch.stack(thetas, -1), torch.stack(omegas, -1)
    return (_wrap(theta) if wrap else theta), omega


class PixelPendulum:
    """The pixel pendulum's ground truth: gym dynamics, energy, frames.

    ``θ`` is the hanging angle (module docstring), ``ω = θ̇``. The reference's
    "canonical" coordinates are ``(q, p) = (θ, c·θ̇)`` with ``c = 0.25``
    (``momentum_scale``), chosen, in its words, so that ``H = PE + KE·c`` "is as close to
    constant as possible". With ``θ̈ = −(3g/2l) sin θ`` the conserved energy is
    proportional to ``(3g/2l)(1 − cos θ) + θ̇²/2``; times ``2c²`` it reads
    ``α (1 − cos q) + p²`` with ``α = 3gc²/l = 1.875``, the default ``energy_coef``
    (the reference's evaluation fits ``α = 1.9``: pass ``energy_coef=1.9``). In
    continuous time these ``(q, p)`` obey Hamilton's equations of ``2H``:
    ``dq/dt = 4p``, ``dp/dt = −3.75 sin q``; ``H`` is conserved all the same.

    Initial states as the reference: gym's ``reset`` repeated until
    ``|θ| < max_angle = π/6``, i.e. ``θ ~ U(−π/6, π/6)``, ``θ̇ ~ U(−1, 1)`` independently.

    Args:
        dt, g, l, m, max_speed: gym's constants.
        momentum_scale: ``c`` in ``p = c·θ̇``.
        energy_coef: ``α`` of ``α(1 − cos q) + p²``; default ``3gc²/l`` (1.875).
        max_angle, max_omega: bounds of ``|θ₀|`` and ``|θ̇₀|``.
    """

    def __init__(
        self,
        dt: float = 0.05,
        g: float = 10.0,
        l: float = 1.0,
        m: float = 1.0,
        max_speed: float = 8.0,
        momentum_scale: float = 0.25,
        energy_coef: float | None = None,
        max_angle: float = math.pi / 6,
        max_omega: float = 1.0,
    ) -> None:
        self.dt, self.g, self.l, self.m, self.max_speed = dt, g, l, m, max_speed
        self.momentum_scale = momentum_scale
        self.energy_coef = 3 * g * momentum_scale**2 / l if energy_coef is None else energy_coef
        self.max_angle, self.max_omega = max_angle, max_omega

    def energy(self, q: Tensor, p: Tensor | None = None) -> Tensor:
        """``α (1 − cos q) + p²``: ``energy(q, p)`` with ``q, p (...)``, or ``energy(y)``
        with ``y = (q, p)`` of shape ``(..., 2)``; returns ``(...)``."""
        if p is None:
            q, p = q.unbind(-1)
        return self.energy_coef * (1 - torch.cos(q)) + p**2

    def to_canonical(self, theta: Tensor, omega: Tensor) -> Tensor:
        """``(θ, ω) -> (q, p) = (θ, c·ω)``: shapes ``(...)`` → ``(..., 2)``."""
        theta, omega = torch.broadcast_tensors(theta, omega)
        return torch.stack([theta, self.momentum_scale * omega], dim=-1)

    def sample_initial(self, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """``(θ₀, θ̇₀)``, each ``(n,)`` float64: ``U(−max_angle, max_angle)`` and
        ``U(−max_omega, max_omega)``, drawn as one ``(n, 2)`` uniform block."""
        u = torch.rand(n, 2, generator=generator, dtype=torch.float64) * 2 - 1
        return u[:, 0] * self.max_angle, u[:, 1] * self.max_omega

    def simulate(
        self, theta0: Tensor, omega0: Tensor, n_steps: int, **kwargs
    ) -> tuple[Tensor, Tensor]:
        """:func:`simulate_gym_pendulum` with this system's constants:
        ``(θ, ω)`` of shape ``(..., n_steps + 1)``."""
        return simulate_gym_pendulum(
            theta0, omega0, n_steps, self.dt, self.g, self.l, self.m,
            max_speed=self.max_speed, **kwargs,
        )  # fmt: skip

    @staticmethod
    def render(theta: Tensor, size: int = 28, **kwargs) -> Tensor:
        """Frames ``(..., size, size)``: :func:`hnn_pl.render.render_pendulum`."""
        return render_pendulum(theta, size, **kwargs)
