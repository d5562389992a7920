"""What the state-space models share: the derivative and trajectory objectives, their
losses and metrics, the learned states; the optimiser and schedule are the recipe's
(:mod:`hnn_pl.models.recipe`)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import torch
from torch import Tensor, nn
from torchmetrics import MeanSquaredError

from hnn_pl.models.recipe import RecipeModel, is_count, is_weight
from hnn_pl.nets.mlp import check_angle_pairs, check_angles

OBJECTIVES = ("derivative", "trajectory")
LEARNED_STATES = ("none", "sample", "trajectory")

#: the training objective's discrepancies (``loss``)
DISCREPANCIES = {"mse": nn.functional.mse_loss, "l1": nn.functional.l1_loss}

#: the options only the trajectory objective uses, with their defaults
TRAJECTORY_OPTIONS: dict[str, Any] = {
    "traj_method": "rk4",
    "substeps": 1,
    "learned_states": "none",
    "state_weight": 1.0,
    "continuity_weight": 0.0,
    "reinit_states": False,
}
#: of those, the ones that act on learned states only
STATES_OPTIONS = ("state_weight", "continuity_weight", "reinit_states")

#: the checkpoint key of :func:`observed_data` of the data the learned states were learned on
STATES_KEY = "hnn_pl_states_data"


def angle_inputs(model: Any) -> dict[str, Any]:
    """How ``model``'s networks read angles: the ``MLP`` options ``angles`` and
    ``angle_pairs`` (none for a model without them, e.g. the autoencoder HNN)."""
    return dict(
        angles=getattr(model, "angles", ()), angle_pairs=getattr(model, "angle_pairs", False)
    )


def refuse_unused_options(objective: str, learned_states: str, options: dict[str, Any]) -> None:
    """One-line ``ValueError`` naming the options of :data:`TRAJECTORY_OPTIONS` set to
    other than their defaults that would do nothing: all of them with the derivative
    objective, those of :data:`STATES_OPTIONS` without learned states."""
    unused = [
        k
        for k, v in options.items()
        if v != TRAJECTORY_OPTIONS[k]
        and (objective == "derivative" or (learned_states == "none" and k in STATES_OPTIONS))
    ]
    if not unused:
        return
    given = ", ".join(f"{k}={options[k]!r}" for k in unused)
    if objective == "derivative":
        raise ValueError(
            f"model.init_args {given}: only the trajectory objective uses them, and objective "
            "is 'derivative': remove them, or set model.init_args.objective: trajectory"
        )
    raise ValueError(
        f"model.init_args {given}: they act on learned states, and learned_states is 'none': "
        "remove them, or set model.init_args.learned_states: sample (or trajectory)"
    )


def observations_fingerprint(obs_y: Tensor, obs_t: Tensor, obs_traj: Tensor) -> str:
    """SHA-256 (hex) over the dtype, shape and bytes of a training split's observed
    samples ``obs_y (S, ·)``, times ``obs_t (S,)`` and trajectory ids ``obs_traj (S,)``,
    as served: equal exactly when the observations are (one pass over ``S·(D + 2)``
    values)."""
    import hashlib

    digest = hashlib.sha256()
    for name, value in (("y", obs_y), ("t", obs_t), ("traj", obs_traj)):
        value = value.detach().cpu().contiguous()
        digest.update(f"{name}:{value.dtype}:{tuple(value.shape)}".encode())
        digest.update(value.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def observed_data(
    obs_y: Tensor, obs_t: Tensor, obs_traj: Tensor, source: str, learned_states: str
) -> dict[str, Any]:
    """What learned states are learned on: ``{"sha256"}`` (:func:`observations_fingerprint`),
    ``{"source"}`` (a name for messages) and ``{"rows"}``, the number of states they give
    (``S`` for ``"sample"``, the ``M`` trajectories for ``"trajectory"``)."""
    rows = len(obs_y) if learned_states == "sample" else int(torch.unique(obs_traj).numel())
    sha = observations_fingerprint(obs_y, obs_t, obs_traj)
    return {"sha256": sha, "source": source, "rows": rows}


def data_source(datamodule: Any) -> str:
    """A DataModule's data named for messages: its class and recording path, or its
    system, number of trajectories and seed; ``keep_fraction`` and ``observe`` when not
    the defaults."""
    name = type(datamodule).__name__
    path = getattr(datamodule, "path", None)
    if path is not None:
        what = f"{name} {path}"
    else:
        system = (getattr(datamodule, "hparams", None) or {}).get("system") or {}
        cls = str(system.get("class_path", "")).rsplit(".", 1)[-1]
        seed = getattr(datamodule, "seed", None)
        n = getattr(datamodule, "n_trajectories", None)
        parts = [cls] if cls else []
        parts += [f"{n} trajectories"] if isinstance(n, int) else []
        parts += [f"seed {seed}"] if seed is not None else []
        what = f"{name}({', '.join(parts)})"
    keep = getattr(datamodule, "keep_fraction", 1.0)
    extra = [f"keep_fraction {keep}"] if keep != 1.0 else []
    if getattr(datamodule, "observe", "states") != "states":
        extra.append(f"observe {datamodule.observe}")
    return what + (f" ({', '.join(extra)})" if extra else "")


def same_data(a: dict[str, Any] | None, rows_a: int, b: dict[str, Any] | None, rows_b: int) -> bool:
    """Whether states learned on ``a`` (``rows_a`` of them) fit data ``b``: the same
    fingerprint; without one on either side, the same number of states."""
    if a and b and a.get("sha256") and b.get("sha256"):
        return a["sha256"] == b["sha256"]
    return rows_a == rows_b


def other_data(
    where: str, saved: dict[str, Any] | None, states: Tensor, data: dict[str, Any]
) -> str:
    """The one line refusing ``states`` learned on ``saved`` for a fit on ``data``."""

    def named(d: dict[str, Any] | None, rows: int) -> str:
        if not d:
            return f"data without a fingerprint ({rows} states)"
        return f"{d['source']} (data {d['sha256'][:12]}, {d['rows']} states)"

    return (
        f"{where}: its learned states were learned on {named(saved, len(states))}, but this fit's "
        f"data is {named(data, data['rows'])}: fit on the data they were learned on, or set "
        "model.init_args.reinit_states: true to start them from these observations"
    )


def forget_last_parameter(checkpoint: dict[str, Any]) -> None:
    """Drop, in ``checkpoint``'s optimiser states, the moments of the last parameter
    (the learned states: :meth:`DynamicsModel.param_groups` puts them last), which start
    anew; L-BFGS keeps one history over all parameters: dropped whole."""
    for opt in checkpoint.get("optimizer_states") or []:
        groups = opt.get("param_groups") or []
        if len(groups) == 1:
            opt["state"] = {}
        elif groups and groups[-1].get("params"):
            (opt.get("state") or {}).pop(groups[-1]["params"][-1], None)


def with_momenta(obs_y: Tensor, obs_t: Tensor, obs_traj: Tensor, state_dim: int) -> Tensor:
    """Observed samples as states ``(S, 2k)``: ``obs_y`` itself when it holds states;
    for positions alone ``obs_y (S, k)``, ``(q, v̂)`` with ``v̂`` the local quadratic
    fit's velocity (:func:`~hnn_pl.data.differences.smoothed_velocity`), i.e. the
    momenta in the gauge ``p = q̇`` (unit mass). From positions the momenta are fixed
    only up to a canonical change that keeps ``q``; this start makes the learned
    ``H_θ``'s kinetic term ``≈ ½|p|²`` near the data and carries a denoised velocity
    (noise ``~σ/(Δt·5^{3/2})`` against central differences' ``σ/(√2 Δt)``)."""
    if obs_y.shape[-1] == state_dim:
        return obs_y
    from hnn_pl.data.differences import smoothed_velocity

    v = smoothed_velocity(obs_y.double(), obs_t.double(), obs_traj)
    return torch.cat([obs_y, v.to(obs_y.dtype)], -1)


def check_options(
    input_dim: Any, hidden_dim: Any, n_hidden: Any, objective: Any, options: dict[str, Any]
) -> None:
    """One-line ``ValueError`` for a :class:`DynamicsModel` option out of its range: the
    sizes, ``objective``, and the trajectory ``options`` (:data:`TRAJECTORY_OPTIONS`:
    their values, and those that would do nothing, :func:`refuse_unused_options`)."""
    from hnn_pl.integrate import WINDOW_METHODS

    if not (
        is_count(input_dim, 2)
        and input_dim % 2 == 0
        and is_count(hidden_dim)
        and is_count(n_hidden)
    ):
        raise ValueError(
            "input_dim must be even and >= 2 (y = (q, p)), hidden_dim and n_hidden >= 1; "
            f"got input_dim={input_dim}, hidden_dim={hidden_dim}, n_hidden={n_hidden}"
        )
    o = options
    choices = (*OBJECTIVES, "auto")
    for ok, message in [
        (objective in choices, f"objective must be one of {choices}: {objective!r}"),
        (
            o["traj_method"] in WINDOW_METHODS,
            f"traj_method must be one of {WINDOW_METHODS}: {o['traj_method']!r}",
        ),
        (is_count(o["substeps"]), f"substeps must be an integer >= 1: {o['substeps']}"),
        (
            o["learned_states"] in LEARNED_STATES,
            f"learned_states must be one of {LEARNED_STATES}: {o['learned_states']!r}",
        ),
        (
            is_weight(o["state_weight"]),
            f"state_weight must be finite and >= 0: {o['state_weight']}",
        ),
        (
            is_weight(o["continuity_weight"]),
            f"continuity_weight must be finite and >= 0: {o['continuity_weight']}",
        ),
        (
            isinstance(o["reinit_states"], bool),
            f"reinit_states must be true or false: {o['reinit_states']!r}",
        ),
    ]:
        if not ok:
            raise ValueError(message)
    refuse_unused_options(objective, o["learned_states"], options)
    if o["continuity_weight"] and o["learned_states"] != "sample":
        raise ValueError(
            f"continuity_weight > 0 only with learned_states: sample: {o['continuity_weight']} "
            f"with {o['learned_states']!r}"
        )


class DynamicsModel(RecipeModel):
    """A LightningModule that learns ``dy/dt = f_θ(y)`` from derivatives or from trajectories.

    Subclasses implement :meth:`build_field`; ``field`` (public) is the plain module it
    returns, with ``vector_field(t, y)`` (and ``hamiltonian(y)`` for an HNN): what
    rollouts integrate. Logs ``train/loss`` every step and ``val/loss``, ``test/loss``
    as the MSE over the whole split (torchmetrics).

    **Derivative objective** (``objective="derivative"``, the paper's): batches are
    ``(y, dydt)``, both ``(B, 2k)``; the loss is ``mean((f_θ(y) − dy/dt)²)``.

    **Trajectory objective** (``objective="trajectory"``; data with ``window: K``):
    batches are windows ``(y (B, K, 2k), t (B, K), index (B, K))`` of ``K``
    consecutive observed samples (``index``: rows of the DataModule's
    ``obs_*_train`` table). From each window's start ``ŷ_0`` the field is integrated
    to the window's times in one batched call
    (:func:`~hnn_pl.integrate.odeint_windows`: ``traj_method``, ``substeps`` equal
    steps of each row's own size between samples, so uneven spacing is exact), and

    ``loss = mean_{b, k≥1, d} (ŷ_k − y_k)² + state_weight · mean_{b, d} (ŷ_0 − y_0)²
    + continuity_weight · mean_{b, k≥1, d} (ŷ_k − s_k)²``.

    ``ŷ_0`` is the observed ``y_0`` (``learned_states="none"``; the second term is 0),
    a learned denoised state per observed sample (``"sample"``: a parameter
    ``(S, 2k)`` started at the observations), or a learned state per trajectory at
    its first sample, integrated to the window's start in the same call
    (``"trajectory"``: ``(M, 2k)``; SRNN's initial-state optimisation). The learned
    states are sized from the DataModule at ``setup`` (:meth:`init_states`), carry
    no weight decay and are saved in checkpoints. The last term (``"sample"`` only)
    ties the learned states ``s_k`` of a window's later samples to the integration from
    its first: multiple shooting, so that the information of a whole trajectory reaches
    every state and the field through windows of a few samples. ``val/loss`` and ``test/loss``:
    the first term on held-out windows from their observed starts.

    **Learned states belong to their data.** With the states, a checkpoint keeps the
    SHA-256 of the training observations they were learned on and a name for them
    (:func:`observed_data`). A fit resumed from it (``fit --ckpt_path``), or a second
    fit of the same object, on other observations is refused in one line naming both
    (never a size mismatch, never the old states used silently), unless
    ``reinit_states``: then the states start anew from the new observations (and
    their optimiser moments with them); the field's weights are kept.

    **Options act or are refused.** The options only the trajectory objective uses
    (:data:`TRAJECTORY_OPTIONS`) set to other than their defaults with
    ``objective="derivative"``, and those acting on learned states without them, are
    refused in one line; so are data it would not use (:meth:`check_data`).

    Args:
        input_dim: ``2k``, the state size (linked from the DataModule by the CLI).
        hidden_dim: ``h``, the MLP's width (200 in the paper).
        n_hidden: number of hidden layers (2).
        activation: hidden nonlinearity (``"tanh"``).
        objective: ``"derivative"``, ``"trajectory"`` or ``"auto"``: the trajectory
            objective for data that serve windows (``window`` set), else the
            derivative one, fixed when the model first sees its data.
        loss: the training objective's discrepancy, of either objective and of every
            term: ``"mse"`` (mean squared) or ``"l1"`` (mean absolute; the
            constrained-HNN reference's, which on the chain pendulum's 100 chunks
            halved the structured HNN's rollout error). ``val/loss`` and ``test/loss``
            are mean squared whatever it is, so runs compare.
        traj_method: fixed-step method of the trajectory objective: ``"rk4"``,
            ``"leapfrog"``, ``"implicit_midpoint"`` (or ``"euler"``).
        substeps: integration steps between consecutive samples.
        learned_states: ``"none"``, ``"sample"`` or ``"trajectory"``.
        state_weight: weight of the learned states' fit to the observations.
        continuity_weight: weight of the integration's fit to the learned states of
            the window's later samples (``learned_states="sample"``; 0: off).
        reinit_states: on observations other than the learned states were learned on
            (a resumed fit, a second fit): start them anew from these instead of
            refusing (``False``).
        angles: indices ``i < k`` of the coordinates ``q_i`` that are angles: the
            networks read them as ``(cos q_i, sin q_i)`` (:class:`~hnn_pl.nets.MLP`), so
            the model is ``2π``-periodic in them however far they turn (``None``: none;
            a model whose networks cannot take them refuses them).
        angle_pairs: the angles' pairwise differences and sums enter the networks too,
            as ``(cos, sin)`` (two angles or more; :class:`~hnn_pl.nets.MLP`): a chain's
            mass matrix, a function of ``θ_i − θ_j``, is then a function of inputs.
        **kwargs: the training recipe, :class:`~hnn_pl.models.recipe.RecipeModel`'s
            ``lr``, ``weight_decay``, ``optimizer``, ``schedule``, … (the paper's: Adam,
            constant rate).
    """

    def __init__(
        self,
        input_dim: int = 2,
        hidden_dim: int = 200,
        n_hidden: int = 2,
        activation: str = "tanh",
        objective: str = "auto",
        loss: str = "mse",
        traj_method: str = "rk4",
        substeps: int = 1,
        learned_states: str = "none",
        state_weight: float = 1.0,
        continuity_weight: float = 0.0,
        reinit_states: bool = False,
        angles: list[int] | None = None,
        angle_pairs: bool = False,
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        options = dict(
            traj_method=traj_method,
            substeps=substeps,
            learned_states=learned_states,
            state_weight=state_weight,
            continuity_weight=continuity_weight,
            reinit_states=reinit_states,
        )
        check_options(input_dim, hidden_dim, n_hidden, objective, options)
        if loss not in DISCREPANCIES:
            raise ValueError(f"model.init_args.loss must be one of {list(DISCREPANCIES)}: {loss!r}")
        self.loss = loss
        self.objective, self.traj_method, self.substeps = objective, traj_method, substeps
        self.learned_states, self.state_weight = learned_states, state_weight
        self.continuity_weight, self.reinit_states = continuity_weight, reinit_states
        #: what the learned states were learned on (:func:`observed_data`), or ``None``
        self.states_data: dict[str, Any] | None = None
        #: the angle coordinates the networks read as ``(cos, sin)`` (``build_field`` uses it)
        self.angles = check_angles(angles, input_dim // 2)
        check_angle_pairs(angle_pairs, self.angles, "model.init_args.angle_pairs")
        self.angle_pairs = angle_pairs
        self.field = self.build_field(input_dim, hidden_dim, n_hidden, activation)
        if self.angles and not any(getattr(m, "angles", ()) for m in self.field.modules()):
            raise ValueError(
                f"model.init_args.angles: {type(self).__name__}'s networks do not read angles "
                "as (cos, sin): remove angles"
            )
        self.register_parameter("states", None)
        self.register_buffer("traj_first", None, persistent=False)
        self.register_buffer("obs_t_train", None, persistent=False)
        self.val_mse = MeanSquaredError()
        self.test_mse = MeanSquaredError()

    def build_field(
        self, input_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> nn.Module:
        """The plain module holding the parameters, with ``vector_field(t, y)``."""
        raise NotImplementedError

    def vector_field(self, t: Tensor | float | None, y: Tensor) -> Tensor:
        """``f_θ(t, y)``: ``(batch, 2k) -> (batch, 2k)``, for ``odeint`` or scipy; ``y``
        of any float dtype (evaluated in the model's, returned in ``y``'s)."""
        return self.in_own_dtype(lambda y: self.field.vector_field(t, y), y)

    def forward(self, y: Tensor) -> Tensor:
        return self.field.vector_field(None, y)

    def rollout(self, y0: Tensor, t: Tensor, method: str = "dopri5", **kwargs) -> Tensor:
        """Integrate the learned field in the model's dtype: ``y0 (batch, 2k)``, ``t (T,)``
        -> ``(T, batch, 2k)``; ``kwargs`` go to :func:`hnn_pl.odeint`. For energies and
        ``H_θ`` as well, use :func:`hnn_pl.rollout`."""
        from hnn_pl.evaluation import rollout

        return rollout(self, y0, t, method=method, dtype="model", **kwargs).y_pred

    # ------------------------------------------------------------ learned states

    def init_states(
        self,
        obs_y: Tensor,
        obs_t: Tensor,
        obs_traj: Tensor,
        source: str = "the given observations",
    ) -> None:
        """Create the learned states from the training split's observed samples
        ``obs_y (S, 2k)`` (or positions ``(S, k)``), their times ``obs_t (S,)`` and
        trajectory ids ``obs_traj (S,)`` (contiguous, time-ordered): ``(S, 2k)`` for
        ``"sample"``, each trajectory's first sample ``(M, 2k)`` for ``"trajectory"``;
        nothing for ``"none"`` or for the derivative objective.

        States that exist already are kept if they were learned on these observations
        (the same :func:`observed_data` fingerprint); learned on other data (a second
        fit of this object on another DataModule) they raise a one-line ``ValueError``
        naming both, or with ``reinit_states`` are made anew from these. ``source``
        names the observations in that message."""
        if self.learned_states == "none" or self.objective != "trajectory":
            return
        data = observed_data(obs_y, obs_t, obs_traj, source, self.learned_states)
        if self.states is not None and not same_data(
            self.states_data, len(self.states), data, data["rows"]
        ):
            if not self.reinit_states:
                raise ValueError(other_data("this model", self.states_data, self.states, data))
            self.states = None
        first = torch.ones_like(obs_traj, dtype=torch.bool)
        first[1:] = obs_traj[1:] != obs_traj[:-1]
        self.traj_first = first.nonzero().flatten().to(self.device)
        self.obs_t_train = obs_t.to(self.device, self.dtype)
        if self.states is None:
            full = self.initial_states(obs_y, obs_t, obs_traj)
            init = full if self.learned_states == "sample" else full[self.traj_first]
            self.states = nn.Parameter(init.detach().clone().to(self.device, self.dtype))
        self.states_data = data

    def initial_states(self, obs_y: Tensor, obs_t: Tensor, obs_traj: Tensor) -> Tensor:
        """The observed samples as the field's states ``(S, 2k)``, where learned states
        start: :func:`with_momenta` (a model on other coordinates converts them)."""
        return with_momenta(obs_y, obs_t, obs_traj, self.hparams.input_dim)

    def check_data(self, datamodule: Any, stage: str = "fit") -> None:
        """Refuse, in one line, data this model cannot use as configured (before any run
        is written; the CLI calls it when the classes are built, ``setup`` again):
        windows for the derivative objective or none for the trajectory objective,
        ``keep_fraction`` < 1 with the derivative objective (it thins only the windows'
        tables), and for ``stage="fit"`` positions alone without learned states.
        ``stage="predict"`` passes: its loader serves states whatever the objective."""
        self.resolve_objective(datamodule)
        if stage == "predict":
            return
        window = getattr(datamodule, "window", None)
        keep = getattr(datamodule, "keep_fraction", 1.0)
        if self.objective == "derivative" and window is not None:
            raise ValueError(
                f"data.init_args.window: {window} serves windows, which only the trajectory "
                "objective uses: set model.init_args.objective: trajectory, or window: null"
            )
        if self.objective == "derivative" and keep != 1.0:
            raise ValueError(
                f"data.init_args.keep_fraction: {keep} thins only the observed trajectories, "
                "which the derivative objective does not use: remove it, or set "
                "model.init_args.objective: trajectory (with data.init_args.window)"
            )
        if self.objective == "trajectory" and hasattr(datamodule, "window") and window is None:
            raise ValueError(
                "model.init_args.objective: trajectory needs windows of observed samples: "
                "set data.init_args.window (K >= 2)"
            )
        positions = getattr(datamodule, "observe", "") == "positions"
        if stage == "fit" and positions and self.objective == "trajectory":
            if self.learned_states == "none":
                raise ValueError(
                    "positions alone give no momenta to start a window from: set "
                    "model.init_args.learned_states: sample (or trajectory)"
                )

    def resolve_objective(self, datamodule: Any) -> None:
        """``objective="auto"`` made ``"trajectory"`` for data that serve windows
        (``datamodule.window`` set), else ``"derivative"``; then the trajectory options
        that would do nothing are refused (:func:`refuse_unused_options`), and the
        hyperparameters record the objective in use. Other objectives stay as given
        (:meth:`check_data` refuses data that do not fit them)."""
        if self.objective != "auto":
            return
        window = getattr(datamodule, "window", None)
        objective = "trajectory" if window is not None else "derivative"
        options = {k: getattr(self, k) for k in TRAJECTORY_OPTIONS}
        refuse_unused_options(objective, self.learned_states, options)
        self.objective = self.hparams["objective"] = objective
        if hasattr(self, "_hparams_initial"):
            self._hparams_initial["objective"] = objective

    def setup(self, stage: str) -> None:
        dm = self.trainer.datamodule if self._trainer is not None else None
        if dm is None:
            return
        self.check_data(dm, stage)
        if self.learned_states != "none" and self.objective == "trajectory" and stage == "fit":
            if not hasattr(dm, "obs_y_train"):
                dm.setup(stage)
            self.init_states(dm.obs_y_train, dm.obs_t_train, dm.obs_traj_train, data_source(dm))

    def fit_data(self, datamodule: Any) -> dict[str, Any] | None:
        """What this fit's learned states are (or will be) learned on: those of the
        states it holds, else :func:`observed_data` of ``datamodule``'s training split
        (set up if needed); ``None`` without learned states or observations."""
        if self.learned_states == "none" or self.objective != "trajectory":
            return None
        if self.states is not None and self.states_data is not None:
            return self.states_data
        if datamodule is None:
            return None
        if not hasattr(datamodule, "obs_y_train"):
            datamodule.setup("fit")
        obs = [getattr(datamodule, f"obs_{k}_train", None) for k in ("y", "t", "traj")]
        if any(o is None for o in obs):
            return None
        return observed_data(*obs, data_source(datamodule), self.learned_states)

    def check_checkpoint(
        self,
        checkpoint: dict[str, Any],
        datamodule: Any = None,
        where: str = "the checkpoint",
        stage: str = "test",
    ) -> None:
        """:meth:`RecipeModel.check_checkpoint`, and for ``stage="fit"`` (a resumed fit)
        the learned states: a checkpoint's states learned on other data than this fit's
        (another :func:`observed_data` fingerprint, or without one another number of
        states) are refused in one line naming both, unless ``reinit_states``; a
        checkpoint without states for a model that learns them, or the reverse, too."""
        super().check_checkpoint(checkpoint, datamodule, where, stage)
        if stage != "fit":
            return
        saved = (checkpoint.get("state_dict") or {}).get("states")
        learns = self.learned_states != "none" and self.objective == "trajectory"
        if (saved is not None) != learns:
            has = "holds learned states" if saved is not None else "holds no learned states"
            raise ValueError(
                f"{where} {has} but this model has learned_states={self.learned_states!r} "
                f"(objective {self.objective!r}): resume with the options it was trained with"
            )
        data = self.fit_data(datamodule)
        if saved is None or data is None or self.reinit_states:
            return
        saved_data = checkpoint.get(STATES_KEY)
        if not same_data(saved_data, len(saved), data, data["rows"]):
            raise ValueError(other_data(where, saved_data, saved, data))

    def prepare_load(
        self,
        checkpoint: dict[str, Any],
        datamodule: Any = None,
        where: str = "the checkpoint",
        stage: str = "test",
    ) -> None:
        """:meth:`check_checkpoint`, then fit the learned states to the checkpoint's:
        resuming on the data they were learned on, loaded as saved; on other data with
        ``reinit_states``, this fit's new states replace the saved ones (and their
        optimiser moments are dropped); otherwise (evaluation) the model takes the
        checkpoint's states, whatever their number."""
        self.check_checkpoint(checkpoint, datamodule, where, stage)
        state = checkpoint.get("state_dict") or {}
        saved = state.get("states")
        if saved is None:
            return
        if stage == "fit" and self.states is not None:
            if not same_data(
                checkpoint.get(STATES_KEY), len(saved), self.states_data, len(self.states)
            ):
                state["states"] = self.states.detach().clone()
                checkpoint[STATES_KEY] = self.states_data
                forget_last_parameter(checkpoint)
            return
        if self.states is None or self.states.shape != saved.shape:
            self.states = nn.Parameter(
                torch.zeros_like(saved, dtype=self.dtype, device=self.device)
            )
        self.states_data = checkpoint.get(STATES_KEY)

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        super().on_save_checkpoint(checkpoint)
        if self.states is not None and self.states_data is not None:
            checkpoint[STATES_KEY] = dict(self.states_data)

    def param_groups(self) -> list[dict[str, Any]]:
        """The field's parameters with ``weight_decay``; the learned states without."""
        groups = super().param_groups()
        if self.states is None:
            return groups
        groups[0]["params"] = [p for p in groups[0]["params"] if p is not self.states]
        return [*groups, {"params": [self.states], "weight_decay": 0.0}]

    # ------------------------------------------------------------------ objectives

    def _batch(self, batch: tuple[Tensor, ...]) -> tuple[Tensor, ...]:
        """``batch`` checked against the objective (one-line error on the wrong kind;
        ``"auto"`` not yet resolved, as without a DataModule: resolved by the batch)."""
        window = len(batch) == 3 and batch[0].ndim == 3
        if self.objective == "auto":
            self.resolve_objective(SimpleNamespace(window=batch[0].shape[1] if window else None))
        if window != (self.objective == "trajectory"):
            raise ValueError(
                f"model.objective={self.objective!r} got a batch of "
                f"{'windows (y, t, index)' if window else 'derivative pairs (y, dydt)'}: "
                + (
                    "set data.init_args.window (K >= 2) for the trajectory objective"
                    if not window
                    else "set model.init_args.objective: trajectory, or data window: null"
                )
            )
        return batch

    def integrate_windows(self, y0: Tensor, t: Tensor, substeps: int | Tensor = 0) -> Tensor:
        """The field from ``y0 (B, 2k)`` at ``t[:, 0]`` to ``t (B, K)``: ``(B, K, 2k)``
        (``substeps`` steps per interval; 0: the model's)."""
        from hnn_pl.integrate import odeint_windows

        n = substeps if isinstance(substeps, Tensor) or substeps else self.substeps
        return odeint_windows(self.field.vector_field, y0, t, self.traj_method, n, 1e-6, 1e-8)

    def window_loss(self, batch: tuple[Tensor, Tensor, Tensor]) -> dict[str, Tensor]:
        """The trajectory objective of one window batch (class docstring): ``{"loss",
        "fit"}`` and, with learned states, ``"anchor"`` (their fit to the observations)
        and ``"continuity"`` (with ``continuity_weight``)."""
        y, t, index = batch
        if self.states is None and self.learned_states != "none":
            raise RuntimeError(
                f"learned_states={self.learned_states!r} has no states: train with a DataModule "
                "that serves obs_*_train (set up at fit), or call init_states(...) first"
            )
        if self.states is None:
            pred = self.integrate_windows(y[:, 0], t)
        elif self.learned_states == "sample":
            pred = self.integrate_windows(self.states[index[:, 0]], t)
        else:  # lead-in from the trajectory's first sample, as many steps as the longest
            traj = torch.searchsorted(self.traj_first, index[:, 0].contiguous(), right=True) - 1
            first = self.traj_first[traj]
            times = torch.cat([self.obs_t_train[first].to(t.dtype)[:, None], t], 1)
            lead = int((index[:, 0] - first).max()) * self.substeps
            if lead:
                n = torch.tensor([lead] + [self.substeps] * (t.shape[1] - 1))
                pred = self.integrate_windows(self.states[traj], times, n)[:, 1:]
            else:  # every window starts its trajectory
                pred = self.integrate_windows(self.states[traj], t)
        k = y.shape[-1]  # 2k for states, k for positions alone
        fit = self.discrepancy(pred[:, 1:, :k], y[:, 1:])
        if self.states is None:
            return {"loss": fit}
        anchor = self.discrepancy(pred[:, 0, :k], y[:, 0])
        out = {"loss": fit + self.state_weight * anchor, "fit": fit, "anchor": anchor}
        if self.continuity_weight:
            out["continuity"] = self.discrepancy(pred[:, 1:], self.states[index[:, 1:]])
            out["loss"] = out["loss"] + self.continuity_weight * out["continuity"]
        return out

    def training_loss(self, batch: tuple[Tensor, ...]) -> dict[str, Tensor]:
        batch = self._batch(batch)
        if self.objective == "trajectory":
            return self.window_loss(batch)
        y, dydt = batch
        return {"loss": self.discrepancy(self(y), dydt)}

    def discrepancy(self, pred: Tensor, target: Tensor) -> Tensor:
        """The training objective's ``loss`` between two tensors of one shape: the mean
        of ``(pred − target)²`` (``"mse"``, and while ``polishing``) or of
        ``|pred − target|`` (``"l1"``)."""
        return DISCREPANCIES["mse" if self.polishing else self.loss](pred, target)

    def _eval_pair(self, batch: tuple[Tensor, ...]) -> tuple[Tensor, Tensor]:
        """(prediction, target) of a held-out batch: ``dy/dt``, or a window's samples
        after its observed start."""
        batch = self._batch(batch)
        if self.objective == "trajectory":
            y, t = batch[0], batch[1]
            pred = self.integrate_windows(self.window_starts(y, t), t)[:, 1:, : y.shape[-1]]
            return pred.reshape(-1), y[:, 1:].reshape(-1)
        return self(batch[0]), batch[1]

    def window_starts(self, y: Tensor, t: Tensor) -> Tensor:
        """The states ``(B, 2k)`` held-out windows ``y (B, K, ·)`` at ``t (B, K)`` start
        from: the observed ``y[:, 0]``, or for positions alone ``(q, p)`` with ``q`` the
        observed first position and ``p`` the field's momentum for the velocity fitted
        to the window's first samples (:func:`~hnn_pl.evaluation.observer.momentum_for_velocity`:
        the model's own gauge, no integration)."""
        if 2 * y.shape[-1] != self.hparams.input_dim:
            return y[:, 0]
        from hnn_pl.evaluation.observer import (
            fit_position_velocity,
            float64_field,
            momentum_for_velocity,
        )

        f, eps = float64_field(self.field)
        q64, t64 = y.double(), t.double()
        q0, v0 = fit_position_velocity(t64, q64, min(5, y.shape[1]))
        p0, _ = momentum_for_velocity(f, q0, v0, 8, eps ** (1 / 3))
        return torch.cat([y[:, 0].double(), p0], -1).to(y.dtype)

    def validation_step(self, batch: tuple[Tensor, ...], batch_idx: int) -> None:
        self.val_mse(*self._eval_pair(batch))
        self.log("val/loss", self.val_mse, prog_bar=True)

    def test_step(self, batch: tuple[Tensor, ...], batch_idx: int) -> None:
        self.test_mse(*self._eval_pair(batch))
        self.log("test/loss", self.test_mse)

    def predict_step(self, batch: tuple[Tensor, ...], batch_idx: int) -> Tensor:
        """The predicted ``dy/dt`` of the batch's states, ``(batch, 2k)``; for a window
        batch, the states integrated from each window's observed start, ``(B, K, 2k)``."""
        if len(batch) == 3 and batch[0].ndim == 3:
            return self.integrate_windows(self.window_starts(batch[0], batch[1]), batch[1])
        return self(batch[0])
