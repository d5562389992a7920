"""Mass-matrix-structured models: ``H = ½ pᵀ M_θ(q)⁻¹ p + V_θ(q)`` and its Lagrangian twin."""

from __future__ import annotations

from torch import Tensor

from hnn_pl.models.base import DynamicsModel
from hnn_pl.models.recipe import is_weight
from hnn_pl.models.velocity import VelocityModel
from hnn_pl.nets.lagrangian import (
    MechanicalHamiltonianField,
    MechanicalLagrangianField,
    MechanicalNets,
)


def _nets(model: DynamicsModel, input_dim: int, hidden_dim: int, n_hidden: int, activation: str):
    return MechanicalNets(
        input_dim // 2,
        hidden_dim,
        n_hidden,
        activation,
        model.mass_eps,
        model.shared_trunk,
        model.angles,
        model.inverse_mass,
        model.angle_pairs,
    )


def _check(mass_eps: float, shared_trunk: bool, inverse_mass: bool) -> None:
    if not (is_weight(mass_eps) and mass_eps > 0):
        raise ValueError(f"mass_eps must be finite and > 0: {mass_eps}")
    for name, value in (("shared_trunk", shared_trunk), ("inverse_mass", inverse_mass)):
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false: {value!r}")


class _Mechanical:
    """What the structured pair shares: its nets (:class:`MechanicalNets`) in the field
    class ``FIELD``, and ``M_θ``, ``V_θ`` read from them."""

    FIELD: type

    def build_field(self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str):
        return self.FIELD(_nets(self, input_dim, hidden_dim, n_hidden, activation))

    def mass_matrix(self, q: Tensor) -> Tensor:
        """``M_θ(q)``: ``(B, k) -> (B, k, k)``."""
        return self.field.nets.mass(q)

    def potential(self, q: Tensor) -> Tensor:
        """``V_θ(q)``: ``(B, k) -> (B,)``."""
        return self.field.nets.potential(q)


class MechanicalHNN(_Mechanical, DynamicsModel):
    """``H_θ = ½ pᵀ M_θ(q)⁻¹ p + V_θ(q)`` on ``y = (q, p)``: ``M_θ(q)⁻¹ = L Lᵀ + εI`` with
    ``L = I + R``, ``R`` lower triangular from the ``k(k+1)/2`` outputs of an ``MLP`` of
    ``q`` (:class:`~hnn_pl.nets.lagrangian.CholeskyMass`), symmetric positive definite by
    construction; ``V_θ`` one more output of that ``MLP`` (``shared_trunk``) or its own
    ``MLP(k → h → h → 1)``. ``dy/dt = (M_θ⁻¹p, −½ ∂(pᵀM_θ⁻¹p)/∂q − ∇V_θ)`` without a solve
    (the constrained-HNN reference's parameterisation). The structure of a mechanical
    system in any coordinates (angles included), as DeLaN's in Hamiltonian form.

    ``inverse_mass=False``: the factor gives ``M_θ = L Lᵀ + εI`` instead, ``dy/dt =
    (M_θ⁻¹p, ½ ∂(uᵀM_θu)/∂q − ∇V_θ)`` with ``u = M_θ⁻¹p`` by a Cholesky solve
    (:func:`~hnn_pl.nets.lagrangian.mechanical_hamiltonian_field`); on the spring's and the
    pendulum's fast recipes its rollouts diverge on most seeds (energy MSE medians 1e3 and
    4e4). ``angles`` (a
    :class:`~hnn_pl.models.base.DynamicsModel` option): the angles of ``q`` enter the
    networks as ``(cos, sin)``.

    Args:
        mass_eps: ``ε``, the floor of the factor matrix's eigenvalues (``M_θ``'s, or
            ``M_θ⁻¹``'s with ``inverse_mass``).
        shared_trunk: the factor and ``V_θ`` as two heads of one MLP
            ``k → h → h → k(k+1)/2 + 1`` (default; the cost of one network), or two MLPs.
        inverse_mass: learn the factor of ``M_θ⁻¹`` (default) or of ``M_θ``.
        **kwargs: the arguments of :class:`~hnn_pl.models.base.DynamicsModel`.
    """

    def __init__(
        self,
        mass_eps: float = 1e-3,
        shared_trunk: bool = True,
        inverse_mass: bool = True,
        **kwargs,
    ) -> None:
        _check(mass_eps, shared_trunk, inverse_mass)
        self.mass_eps, self.shared_trunk, self.inverse_mass = mass_eps, shared_trunk, inverse_mass
        super().__init__(**kwargs)

    FIELD = MechanicalHamiltonianField

    def hamiltonian(self, y: Tensor) -> Tensor:
        """``H_θ(y)``: ``(B, 2k) -> (B,)``."""
        return self.field.hamiltonian(y)


class MechanicalLNN(_Mechanical, VelocityModel):
    """``L_θ = ½ q̇ᵀ M_θ(q) q̇ − V_θ(q)`` on ``x = (q, q̇)`` (DeLaN, Lutter et al. 2019): the
    Lagrangian twin of :class:`MechanicalHNN` (the same ``M_θ``, ``V_θ``), accelerations by
    a Cholesky solve with ``M_θ`` (:func:`~hnn_pl.nets.lagrangian.mechanical_acceleration`;
    no Hessian, never singular); energy ``½ q̇ᵀM_θq̇ + V_θ``. Data and objectives:
    :class:`~hnn_pl.models.velocity.VelocityModel`. ``inverse_mass``, ``angles``: as
    :class:`MechanicalHNN`'s (with ``M_θ⁻¹ = A`` learned,
    ``q̈ = (Σ_j ∂A/∂q_j q̇_j) w − A (½ ∂(wᵀAw)/∂q + ∇V_θ)``, ``w = A⁻¹q̇``).

    Args:
        mass_eps: ``ε``, the floor of the factor matrix's eigenvalues.
        shared_trunk: the factor and ``V_θ`` as two heads of one MLP
            ``k → h → h → k(k+1)/2 + 1`` (default; the cost of one network), or two MLPs.
        inverse_mass: learn the factor of ``M_θ⁻¹`` (default) or of ``M_θ``.
        **kwargs: the arguments of :class:`~hnn_pl.models.base.DynamicsModel`.
    """

    def __init__(
        self,
        mass_eps: float = 1e-3,
        shared_trunk: bool = True,
        inverse_mass: bool = True,
        **kwargs,
    ) -> None:
        _check(mass_eps, shared_trunk, inverse_mass)
        self.mass_eps, self.shared_trunk, self.inverse_mass = mass_eps, shared_trunk, inverse_mass
        super().__init__(**kwargs)

    FIELD = MechanicalLagrangianField

    def energy(self, x: Tensor) -> Tensor:
        """``E_θ(q, q̇) = ½ q̇ᵀM_θq̇ + V_θ``: ``(B, 2k) -> (B,)``."""
        return self.field.energy(x)

    def hamiltonian(self, y: Tensor) -> Tensor:
        """The learned energy in the data's coordinates (``field.hamiltonian``)."""
        return self.field.hamiltonian(y)
