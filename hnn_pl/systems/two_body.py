"""Two-body problem (paper task 4): two equal masses in near-circular orbits."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from hnn_pl.systems.nbody import NBody


class TwoBody(NBody):
    """Two bodies under Newtonian gravity (state layout of :mod:`hnn_pl.systems.nbody`).

    Initial states as the reference's two-body ``random_config``
    (``experiment-orbits/data.py``, published as ``experiment-2body/data.py``): body 0
    at ``q_0`` with *each coordinate* ``U[0.5, 1.5]`` (first quadrant, no random
    rotation), ``r = |q_0|``, velocity ``v_0 = (−q_0y, q_0x) · √(G m) / (2 r^{3/2})``
    (the circular speed ``√(G m / 4r)`` for separation ``2r``, counter-clockwise) times
    one scalar ``1 + ν·N(0, 1)`` per orbit (``ν = 0.05``), body 1 = −body 0 in position
    and velocity, ``p = m v``. Centre of mass and total momentum are exactly zero.

    Args:
        mass: the mass of each body.
        G: gravitational constant.
        orbit_noise: ``ν``; 0 gives exactly circular orbits.
        radius: ``(min_radius, max_radius)``, the range of *each coordinate* of body 0.
    """

    def __init__(
        self,
        mass: float = 1.0,
        G: float = 1.0,
        orbit_noise: float = 0.05,
        radius: tuple[float, float] = (0.5, 1.5),
    ) -> None:
        super().__init__(2, mass, G, orbit_noise, radius)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        m, f64 = self._equal_mass(), torch.float64
        pos = torch.rand(n, 2, generator=generator, dtype=f64)
        pos = pos * (self.radius[1] - self.radius[0]) + self.radius[0]
        r = pos.norm(dim=-1, keepdim=True)
        vel = torch.stack([-pos[:, 1], pos[:, 0]], dim=-1) * math.sqrt(self.G * m) / (2 * r**1.5)
        vel = vel * (1 + self.orbit_noise * torch.randn(n, 1, generator=generator, dtype=f64))
        q, v = torch.stack([pos, -pos], dim=1), torch.stack([vel, -vel], dim=1)
        return self.join(q, m * v)
