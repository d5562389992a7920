"""Models whose own states are ``(q, q̇)`` (Lagrangian ones) on the project's ``(q, p)`` data.

A model declares ``coordinates = "velocity"`` and its field is a
:class:`~hnn_pl.nets.lagrangian.VelocityField`. :class:`VelocityModel` converts what it is
given with the data's system (:class:`VelocityChart`): training and held-out batches to
``(q, q̇)`` (and ``dy/dt`` to ``(q̇, q̈)``); its field, which evaluation reads, back to the
data's ``(q, p)``. Data without a system (a recording) are read as ``(q, q̇)`` already, as
are positions alone (their states are started with a fitted velocity).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.func import grad, jvp, vmap

from hnn_pl.models.base import DynamicsModel


class VelocityChart:
    """``(q, p) ↔ (q, q̇)`` of a Hamiltonian system: ``q̇ = ∂H/∂p (q, p)`` (the system's
    field), ``p = system.momentum_qv(q, q̇)``, and the time derivatives between them from
    ``H``'s second derivatives (``torch.func`` of ``system.hamiltonian``, which must be
    plain torch operations, as every bundled system's is). Computed in ``float64``.

    Args:
        system: a :class:`~hnn_pl.systems.base.HamiltonianSystem`.
    """

    def __init__(self, system: Any) -> None:
        from hnn_pl.systems.base import HamiltonianSystem

        self.system, self.dof = system, int(system.dof)
        #: whether the system gives ``momentum_qv`` in closed form (differentiable)
        self.closed_form = type(system).momentum_qv is not HamiltonianSystem.momentum_qv

    def _velocity(self, y: Tensor) -> Tensor:
        return grad(lambda z: self.system.hamiltonian(z).sum())(y)[..., self.dof :]

    def to_velocity(self, y: Tensor) -> Tensor:
        """``(q, p) -> (q, ∂H/∂p)``: ``(..., 2k) -> (..., 2k)``, in ``y``'s dtype."""
        y64 = y.detach().double()
        v = self.system.vector_field(None, y64)[..., : self.dof]
        return torch.cat([y64[..., : self.dof], v], -1).to(y.dtype)

    def to_momentum(self, x: Tensor) -> Tensor:
        """``(q, q̇) -> (q, momentum_qv(q, q̇))``: ``(..., 2k) -> (..., 2k)``."""
        q, v = x.detach().double().chunk(2, -1)
        return torch.cat([q, self.system.momentum_qv(q, v)], -1).to(x.dtype)

    def rates(self, y: Tensor, dydt: Tensor) -> Tensor:
        """``(q̇, q̈)`` along the motion ``dy/dt`` at ``y``: ``q̈ = d/dt ∂H/∂p``, one
        Jacobian–vector product: ``(B, 2k), (B, 2k) -> (B, 2k)``."""
        y64, d64 = y.detach().double(), dydt.detach().double()
        v, a = jvp(self._velocity, (y64,), (d64,))
        return torch.cat([v, a], -1).to(y.dtype)

    def momentum_rate(self, y: Tensor, x: Tensor, a: Tensor) -> Tensor:
        """``ṗ`` of the motion with ``(q̇, q̈) = (x[..., k:], a)`` at ``y = (q, p)``: from
        ``q̈ = ∂²H/∂p∂q q̇ + ∂²H/∂p² ṗ``, ``ṗ = (∂²H/∂p²)⁻¹ (q̈ − ∂²H/∂p∂q q̇)``;
        ``(B, 2k), (B, 2k), (B, k) -> (B, k)``, differentiable in ``a``. A system with a
        closed-form ``momentum_qv`` gives it as one Jacobian–vector product instead,
        ``ṗ = d/dt momentum_qv(q, q̇)`` along ``(q̇, q̈)``."""
        k = self.dof
        if self.closed_form:
            q, v = x.detach().double().chunk(2, -1)
            _, p_dot = jvp(self.system.momentum_qv, (q, v), (v, a.double()))
            return p_dot.to(a.dtype)
        y64, v = y.detach().double(), x[..., k:].detach().double()
        eye = torch.eye(2 * k, dtype=torch.float64, device=y.device)[k:]
        dirs = torch.cat([eye[:, None].expand(k, *y64.shape), torch.cat([v, 0 * v], -1)[None]])
        cols = vmap(lambda d: jvp(self._velocity, (y64,), (d,))[1])(dirs)
        h_pp = cols[:k].permute(1, 2, 0)
        rhs = a.double() - cols[k]
        return torch.linalg.solve(h_pp.to(a.dtype), rhs.to(a.dtype))


def chart_of(system: Any) -> VelocityChart | None:
    """The chart of a data's system, or ``None`` without one."""
    return None if system is None else VelocityChart(system)


def system_from_spec(spec: Any) -> Any:
    """The system of a checkpoint's ``datamodule_hyper_parameters["system"]``
    (``{"class_path", "init_args"}``) if its class is already imported (the package's
    systems are; a name read from a file is never imported), or ``None``."""
    if not (isinstance(spec, dict) and spec.get("class_path")):
        return None
    import hnn_pl.systems  # noqa: F401 - the bundled systems, by their own names
    from hnn_pl.safe_io import loaded_class

    cls = loaded_class(str(spec["class_path"]))
    return None if cls is None else cls(**(spec.get("init_args") or {}))


def _versioned(batch: tuple[Tensor, ...]) -> tuple[tuple[Tensor, int], ...]:
    """The batch's tensors with their in-place versions (held: their ids stay theirs)."""
    return tuple((t, t._version) for t in batch)


def _same_tensors(saved: tuple[tuple[Tensor, int], ...], batch: tuple[Tensor, ...]) -> bool:
    """Whether ``batch`` holds the very tensors of ``saved``, unmodified since."""
    return len(saved) == len(batch) and all(
        t is b and t._version == v for (t, v), b in zip(saved, batch)
    )


class VelocityModel(DynamicsModel):
    """A :class:`~hnn_pl.models.base.DynamicsModel` on ``x = (q, q̇)``; its field a
    :class:`~hnn_pl.nets.lagrangian.VelocityField`.

    **Data.** Batches come as the project serves them, ``(q, p)``; with the data's
    system attached (:meth:`attach_system`: done at ``setup`` from the DataModule's
    ``system``, and when a checkpoint is loaded, from the DataModule or the system the
    checkpoint records) they are converted by its :class:`VelocityChart`: states to
    ``(q, q̇)``, targets ``dy/dt`` to ``(q̇, q̈)``. Without a system the data are read as
    ``(q, q̇)``.

    **Objectives.** Derivative: ``loss = mean((q̈_θ(q, q̇) − q̈)²)`` (also ``val/loss``,
    ``test/loss``). Trajectory: the windows in ``(q, q̇)``, integrated with the field's
    own ``(q̇, q̈_θ)``; learned states live in ``(q, q̇)``.

    **Evaluation.** ``model.field.vector_field``/``hamiltonian`` take the data's ``(q, p)``
    through the chart (``(q, q̇)`` without one): rollouts, ``predict`` and the metrics
    read it as any other model's; ``hamiltonian`` is the learned energy, logged as the
    conserved quantity.
    """

    coordinates = "velocity"

    def attach_system(self, system: Any) -> None:
        """Read the data through ``system``'s chart (``None``: the data are ``(q, q̇)``)."""
        self.field.chart = chart_of(system)

    @property
    def chart(self) -> VelocityChart | None:
        return self.field.chart

    def to_velocity(self, y: Tensor) -> Tensor:
        """States ``(..., 2k)`` of the data in ``(q, q̇)`` (as they are without a chart)."""
        return y if self.chart is None else self.chart.to_velocity(y)

    def _batch(self, batch: tuple[Tensor, ...]) -> tuple[Tensor, ...]:
        """The batch checked, then in ``(q, q̇)``. The last conversion is kept with the
        tensors it was made from: a full-batch fit, served the same tensors every step,
        converts them once (the chart's derivatives of ``H`` cost as much as a step)."""
        batch = super()._batch(batch)
        if self.chart is None:
            return batch
        last = getattr(self, "_last_conversion", None)
        if last is not None and last[2] is self.chart and _same_tensors(last[0], batch):
            return last[1]
        if self.objective == "trajectory":
            y = batch[0]
            y = self.to_velocity(y) if y.shape[-1] == self.hparams.input_dim else y
            out = (y, *batch[1:])
        else:
            y, dydt = batch
            out = (self.chart.to_velocity(y), self.chart.rates(y, dydt))
        self._last_conversion = (_versioned(batch), out, self.chart)
        return out

    def accelerations(self, x: Tensor) -> Tensor:
        """``q̈_θ`` at ``x = (q, q̇)``: ``(B, 2k) -> (B, k)``."""
        q, v = x.chunk(2, -1)
        return self.field.acceleration(q, v)

    def integrate_windows(self, y0: Tensor, t: Tensor, substeps: int | Tensor = 0) -> Tensor:
        """The field's own ``(q̇, q̈_θ)`` from ``y0 = (q, q̇) (B, 2k)``: ``(B, K, 2k)``."""
        from hnn_pl.integrate import odeint_windows

        n = substeps if isinstance(substeps, Tensor) or substeps else self.substeps
        f = self.field.native_vector_field
        return odeint_windows(f, y0, t, self.traj_method, n, 1e-6, 1e-8)

    def training_loss(self, batch: tuple[Tensor, ...]) -> dict[str, Tensor]:
        reset = getattr(self.field, "reset_counts", None)
        if reset is not None:
            reset()
        if self.objective == "trajectory":
            parts = super().training_loss(batch)
        else:
            x, rates = self._batch(batch)
            k = x.shape[-1] // 2
            parts = {"loss": self.discrepancy(self.accelerations(x), rates[..., k:])}
        if reset is not None:
            parts["singular_fraction"] = self.field.singular_fraction
        return parts

    def _eval_pair(self, batch: tuple[Tensor, ...]) -> tuple[Tensor, Tensor]:
        if self.objective == "trajectory":
            return super()._eval_pair(batch)
        x, rates = self._batch(batch)
        return self.accelerations(x), rates[..., x.shape[-1] // 2 :]

    def window_starts(self, y: Tensor, t: Tensor) -> Tensor:
        """Held-out windows' starts in ``(q, q̇)``: the (converted) first state, or for
        positions alone the first position and the velocity fitted to the window's first
        samples."""
        if 2 * y.shape[-1] != self.hparams.input_dim:
            return y[:, 0]
        from hnn_pl.evaluation.observer import fit_position_velocity

        q0, v0 = fit_position_velocity(t.double(), y.double(), min(5, y.shape[1]))
        return torch.cat([y[:, 0].double(), v0], -1).to(y.dtype)

    def predict_step(self, batch: tuple[Tensor, ...], batch_idx: int) -> Tensor:
        """As :meth:`DynamicsModel.predict_step`, in the data's coordinates."""
        if not (len(batch) == 3 and batch[0].ndim == 3):
            return self(batch[0])
        y, t = batch[0], batch[1]
        y = self.to_velocity(y) if y.shape[-1] == self.hparams.input_dim else y
        x = self.integrate_windows(self.window_starts(y, t), t)
        return x if self.chart is None else self.chart.to_momentum(x)

    def initial_states(self, obs_y: Tensor, obs_t: Tensor, obs_traj: Tensor) -> Tensor:
        """Learned states start from the observations in ``(q, q̇)``: full states
        converted by the chart, positions alone with their fitted velocity."""
        full = super().initial_states(obs_y, obs_t, obs_traj)
        return self.to_velocity(full) if obs_y.shape[-1] == full.shape[-1] else full

    def setup(self, stage: str) -> None:
        dm = self.trainer.datamodule if self._trainer is not None else None
        if dm is not None:
            self.attach_system(getattr(dm, "system", None))
        super().setup(stage)

    def prepare_load(
        self,
        checkpoint: dict[str, Any],
        datamodule: Any = None,
        where: str = "the checkpoint",
        stage: str = "test",
    ) -> None:
        """:meth:`DynamicsModel.prepare_load`, then the system attached: ``datamodule``'s,
        else the one the checkpoint records."""
        super().prepare_load(checkpoint, datamodule, where, stage)
        if datamodule is not None:
            self.attach_system(getattr(datamodule, "system", None))
        else:
            spec = (checkpoint.get("datamodule_hyper_parameters") or {}).get("system")
            self.attach_system(system_from_spec(spec))
