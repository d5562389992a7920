"""Three-body problem (paper's task 4b): three equal masses, perturbed circular orbits."""

from __future__ import annotations

from hnn_pl.systems.nbody import NBody


class ThreeBody(NBody):
    """Three bodies under Newtonian gravity; state layout of :mod:`hnn_pl.systems.nbody`
    (``y = (x_1, y_1, x_2, y_2, x_3, y_3, px_1, …, py_3)``).

    Initial states exactly as the reference's three-body ``random_config``
    (``experiment-3body/data.py``, quoted in :class:`~hnn_pl.systems.nbody.NBody`): a
    radius ``r ~ U[0.9, 1.2]``, body 0 in the direction of a normalised ``U[−1, 1]²``
    draw, bodies 1 and 2 rotated by 120° and 240°, circular-orbit velocities
    ``R(90°) q_k / (3^{1/4} r^{3/2})`` (for ``G = m = 1``), each velocity component then
    multiplied by ``1 + 0.2·U(−1, 1)``. Centre of mass exactly zero; total momentum not.

    Args:
        mass: the mass of each body.
        G: gravitational constant.
        orbit_noise: ``ν`` of the velocity perturbation; 0 gives the circular
            Lagrange solution.
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
