"""The Lagrangian Neural Network: an MLP for ``L_θ(q, q̇)``, accelerations by Euler–Lagrange."""

from __future__ import annotations

from torch import Tensor

from hnn_pl.models.base import angle_inputs
from hnn_pl.models.recipe import is_weight
from hnn_pl.models.velocity import VelocityModel
from hnn_pl.nets import MLP
from hnn_pl.nets.lagrangian import ON_SINGULAR, LagrangianField


class LNN(VelocityModel):
    """``L_θ(q, q̇) = ½ c|q̇|² + MLP(cat(q, q̇))``, ``MLP: 2k → h → h → 1`` (Cranmer et al.
    2020, with a kinetic prior); the field
    on ``(q, q̇)`` is ``(q̇, q̈_θ)`` with
    ``∂²L_θ/∂q̇² q̈_θ = ∂L_θ/∂q − (∂²L_θ/∂q̇∂q) q̇``, one batched solve
    (:func:`~hnn_pl.nets.lagrangian.euler_lagrange`). The learned energy
    ``E_θ = q̇·∂L_θ/∂q̇ − L_θ`` is the model's ``hamiltonian``.

    A row whose ``∂²L_θ/∂q̇²`` is singular or ill-conditioned (``min|λ| ≤ rcond·max|λ|``)
    has no unique acceleration: it is solved with the ridge ``ridge·max(max|λ|, 1)·I``
    and counted, the share of such rows logged as ``train/singular_fraction`` each
    step (``on_singular="ridge"``), or refused with a ``FloatingPointError``
    (``"raise"``). Data and objectives: :class:`~hnn_pl.models.velocity.VelocityModel`.

    ``kinetic_prior = c`` (default 1) makes ``L_θ = ½ c|q̇|² + MLP(q, q̇)``: the
    network corrects a unit-mass kinetic term, so the first steps solve with a Hessian
    near ``cI`` rather than a random MLP's, often nearly singular one (whose accelerations
    threw the spring's first trajectory steps to losses of 1e8); ``0`` is Cranmer et al.'s
    plain ``L_θ = MLP``.

    Args:
        kinetic_prior: ``c``.
        rcond: the relative eigenvalue bound below which a Hessian is singular.
        ridge: the relative ridge of singular rows.
        on_singular: ``"ridge"`` or ``"raise"``.
        **kwargs: the arguments of :class:`~hnn_pl.models.base.DynamicsModel`.
    """

    def __init__(
        self,
        kinetic_prior: float = 1.0,
        rcond: float = 1e-6,
        ridge: float = 1e-3,
        on_singular: str = "ridge",
        **kwargs,
    ) -> None:
        if not (is_weight(kinetic_prior) and is_weight(rcond) and is_weight(ridge) and ridge > 0):
            raise ValueError(
                "kinetic_prior and rcond must be finite and >= 0, ridge > 0: "
                f"{kinetic_prior}, {rcond}, {ridge}"
            )
        if on_singular not in ON_SINGULAR:
            raise ValueError(f"on_singular must be one of {ON_SINGULAR}: {on_singular!r}")
        self.kinetic_prior, self.rcond, self.ridge = kinetic_prior, rcond, ridge
        self.on_singular = on_singular
        super().__init__(**kwargs)

    def build_field(
        self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> LagrangianField:
        net = MLP(input_dim, 1, hidden_dim, n_hidden, activation, **angle_inputs(self))
        return LagrangianField(net, self.kinetic_prior, self.rcond, self.ridge, self.on_singular)

    def lagrangian(self, x: Tensor) -> Tensor:
        """``L_θ(q, q̇)``: ``(B, 2k) -> (B,)``."""
        q, v = x.chunk(2, -1)
        return self.field.lagrangian(q, v)

    def energy(self, x: Tensor) -> Tensor:
        """``E_θ(q, q̇) = q̇·∂L_θ/∂q̇ − L_θ``: ``(B, 2k) -> (B,)``."""
        return self.field.energy(x)

    def hamiltonian(self, y: Tensor) -> Tensor:
        """The learned energy in the data's coordinates (``field.hamiltonian``)."""
        return self.field.hamiltonian(y)
