"""Three-body problem (paper's task 4b): three equal masses, perturbed circular orbits."""

from __future__ import annotations

from hnn_pl.systems.nbody import NBody


class ThreeBody(NBody):
    """Three equal masses: :class:`~hnn_pl.systems.nbody.NBody` with ``n = 3``, whose
    sampler is then exactly the reference's three-body ``random_config``
    (``experiment-3body/data.py``); ``orbit_noise = 0`` gives the circular Lagrange
    solution.

    Args:
        mass: the mass of each body.
        G: gravitational constant.
        orbit_noise: ``ν`` of the velocity perturbation.
        radius: ``(min_radius, max_radius)`` of the circle the bodies start on.
    """

    def __init__(
        self,
        mass: float = 1.0,
        G: float = 1.0,
        orbit_noise: float = 0.2,
        radius: tuple[float, float] = (0.9, 1.2),
    ) -> None:
        super().__init__(3, mass, G, orbit_noise, radius)
