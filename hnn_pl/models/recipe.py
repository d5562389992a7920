"""How every model is trained: optimiser, learning-rate schedule, steps per batch, guards.

One base class, :class:`RecipeModel`, so state and pixel models share the training
loop and every recipe option works for both. Training uses Lightning's manual
optimisation: ``trainer.global_step`` counts optimiser steps, so ``max_steps`` keeps
its meaning whatever ``inner_steps`` is.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from typing import Any

import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_info, rank_zero_warn
from torch import Tensor

from hnn_pl.safe_io import (
    check_finite_weights,
    check_model_class,
    check_same_system,
    check_state_shapes,
    class_name,
)

OPTIMIZERS = ("adam", "adamw", "lbfgs")
SCHEDULES = ("constant", "cosine", "onecycle")
#: skipped non-finite steps (``on_nonfinite="skip"``) after which the fit stops anyway
MAX_SKIPS = 10
#: objective evaluations an L-BFGS step's strong-Wolfe line search may take (torch's own)
MAX_LINE_SEARCH = 25
#: polishing evaluations kept to answer L-BFGS's repeat of the point its last step ended on
KEPT_EVALUATIONS = 4


def is_count(value: Any, least: int = 1) -> bool:
    """Whether ``value`` is an integer (not a bool) ``>= least``."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= least


def is_weight(value: Any) -> bool:
    """Whether ``value`` is a finite real number ``>= 0`` (not a bool)."""
    return (
        isinstance(value, numbers.Real)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value >= 0
    )


class RecipeModel(L.LightningModule):
    """The training loop of every model; subclasses give the loss and parameter groups.

    One training batch runs ``inner_steps`` optimiser steps on it (full-batch tasks:
    Lightning's per-batch work — hooks, logging, loop bookkeeping — is paid once per
    ``inner_steps`` steps). Each step: loss, backward, a non-finite check of the loss
    and of every gradient *before* the update (``on_nonfinite="stop"`` raises
    ``FloatingPointError`` naming the step and the last checkpoint, so no non-finite
    weights are ever saved — a finite loss can have an infinite gradient, and one such
    update makes every weight NaN; ``"skip"`` drops the step, which does not count
    towards ``max_steps``, up to :data:`MAX_SKIPS` times; L-BFGS always stops),
    optional gradient-norm clipping, the optimiser and the schedule.

    **Polishing** (``polish_steps`` P > 0): the last P of ``max_steps`` are L-BFGS
    iterations (strong-Wolfe line search) on the whole training set at once, each a
    step, minimising the squared form of the objective (the absolute error's kinks
    stall a line search; ``polishing`` is true meanwhile); the first optimiser and its
    schedule take the steps before them. The fit ends early, its weights final, at the
    first polishing step that leaves every weight as it was (:meth:`_stop_polishing`;
    ``polish_stopped_at``). A trained field's error keeps falling under
    L-BFGS where Adam's decays slowly: the structured HNN on the chain pendulum's 100
    chunks, seed 0, after 2,000 Adam steps (rollout error 9.1e-3), reached 3.2e-3 in
    1,800 iterations (5 min) where 6,000 more Adam steps (14 min) reached 4.0e-3.

    Learning rate at step ``s`` of ``S`` (``S`` = ``trainer.max_steps`` − P):
    ``constant``: ``lr``; ``cosine``: ``lr·½(1 + cos(π s/S))``; ``onecycle``:
    ``torch.optim.lr_scheduler.OneCycleLR(max_lr=lr)`` (warm-up 30 %, cosine
    annealing, momentum cycling); ``warmup_steps`` > 0 multiplies the first steps by
    ``s/warmup_steps`` (``constant``/``cosine``).

    Args:
        lr: learning rate (peak rate for ``onecycle``; L-BFGS step length).
        weight_decay: L2 coefficient ``λ``: ``λθ`` added to the gradient (Adam, L-BFGS)
            or decoupled decay (AdamW).
        optimizer: ``"adam"`` (paper), ``"adamw"`` or ``"lbfgs"`` (strong-Wolfe line
            search; one optimiser step = one L-BFGS iteration; full batch only).
        schedule: ``"constant"`` (paper), ``"cosine"`` or ``"onecycle"``.
        warmup_steps: linear warm-up length.
        inner_steps: optimiser steps per training batch.
        grad_clip: clip the gradient's global norm to this value (``None``: off).
        on_nonfinite: ``"stop"`` or ``"skip"``.
        polish_steps: L-BFGS iterations on the whole training set that end the fit
            (above; 0: none). Needs ``trainer.max_steps`` (a shorter run, a smoke run
            of a polishing config, polishes its second half, with a warning), one
            process, and data that serve their rows in one object
            (:class:`~hnn_pl.data.base.TensorBatches`).
    """

    def __init__(
        self,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        optimizer: str = "adam",
        schedule: str = "constant",
        warmup_steps: int = 0,
        inner_steps: int = 1,
        grad_clip: float | None = None,
        on_nonfinite: str = "stop",
        polish_steps: int = 0,
    ) -> None:
        super().__init__()
        for ok, message in [
            (is_weight(lr) and lr > 0, f"lr must be finite and > 0, got {lr}"),
            (is_weight(weight_decay), f"weight_decay must be finite and >= 0: {weight_decay}"),
            (optimizer in OPTIMIZERS, f"optimizer must be one of {OPTIMIZERS}, got {optimizer!r}"),
            (schedule in SCHEDULES, f"schedule must be one of {SCHEDULES}, got {schedule!r}"),
            (
                is_count(warmup_steps, 0) and is_count(inner_steps),
                f"need integers warmup_steps >= 0, inner_steps >= 1: {warmup_steps}, {inner_steps}",
            ),
            (
                is_count(polish_steps, 0),
                f"polish_steps must be an integer >= 0: {polish_steps!r}",
            ),
            (
                grad_clip is None or (is_weight(grad_clip) and grad_clip > 0),
                f"grad_clip must be finite and > 0, or null: {grad_clip}",
            ),
            (
                on_nonfinite in ("stop", "skip"),
                f"on_nonfinite must be 'stop' or 'skip': {on_nonfinite}",
            ),
        ]:
            if not ok:
                raise ValueError(message)
        self.save_hyperparameters()  # every subclass's options too (their frames are above)
        self.automatic_optimization = False
        self._skipped = 0
        #: true while an L-BFGS polishing step evaluates the objective (its squared form)
        self.polishing = False
        self._full_batch: Any = None
        #: the step at which polishing stopped, its weights final (:meth:`_stop_polishing`)
        self.polish_stopped_at: int | None = None
        #: polishing evaluations kept (:meth:`_seen_evaluation`): (weights, parts, loss, grads)
        self._evaluations: list[tuple[Tensor, dict[str, Tensor], Tensor, list[Tensor | None]]] = []
        self.recipe = dict(
            lr=lr,
            weight_decay=weight_decay,
            optimizer=optimizer,
            schedule=schedule,
            warmup_steps=warmup_steps,
            inner_steps=inner_steps,
            grad_clip=grad_clip,
            on_nonfinite=on_nonfinite,
            polish_steps=polish_steps,
        )

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["hnn_pl_model_class"] = class_name(type(self))

    def check_checkpoint(
        self,
        checkpoint: dict[str, Any],
        datamodule: Any = None,
        where: str = "the checkpoint",
        stage: str = "test",
    ) -> None:
        """Refuse, in one ``ValueError`` line naming ``where``, a checkpoint (a dict as
        :func:`~hnn_pl.safe_io.load_checkpoint` returns) of another model class (a
        Baseline's weights under an HNN config would otherwise be tested under the HNN's
        name), with non-finite weights, or trained on another system than
        ``datamodule``'s (:func:`~hnn_pl.safe_io.check_same_system`). ``stage``: what
        it is loaded for (``"fit"``: resumed)."""
        check_model_class(checkpoint, type(self), where)
        check_finite_weights(checkpoint, where)
        check_same_system(checkpoint, datamodule, where)

    def prepare_load(
        self,
        checkpoint: dict[str, Any],
        datamodule: Any = None,
        where: str = "the checkpoint",
        stage: str = "test",
    ) -> None:
        """What is done before a checkpoint's state dict is loaded: :meth:`check_checkpoint`
        (subclasses also fit their parameters to the checkpoint's)."""
        self.check_checkpoint(checkpoint, datamodule, where, stage)

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """:meth:`prepare_load` with the trainer's DataModule, checkpoint path and stage
        (none of them in :meth:`load_from_checkpoint`)."""
        trainer = self._trainer
        dm = getattr(trainer, "datamodule", None)
        path = getattr(trainer, "ckpt_path", None)
        fn = getattr(getattr(trainer, "state", None), "fn", None)
        stage = "fit" if fn is not None and fn == "fit" else "test"
        self.prepare_load(checkpoint, dm, f"checkpoint {path}" if path else "the checkpoint", stage)

    def load_trained(
        self, checkpoint: dict[str, Any], datamodule: Any = None, where: str = "the checkpoint"
    ) -> None:
        """Load a checkpoint for evaluation as ``trainer.test(ckpt_path=…)`` does:
        :meth:`prepare_load` (checks; learned states sized as saved), then its state dict,
        strictly; a missing state dict or parameters of other names or shapes than this
        model's are one ``ValueError`` line."""
        state = checkpoint.get("state_dict")
        if not isinstance(state, dict):
            raise ValueError(f"{where}: holds no state_dict (not a Lightning checkpoint)")
        self.prepare_load(checkpoint, datamodule, where, "test")
        check_state_shapes(state, self.state_dict(), where)
        self.load_state_dict(state)

    def check_run(
        self,
        datamodule: Any,
        stage: str,
        checkpoint: dict[str, Any] | None = None,
        where: str = "the checkpoint",
    ) -> None:
        """Everything a run (``stage``: ``fit``, ``validate``, ``test``, ``predict``) can
        refuse before it writes anything: the data (``check_data``, if the model has one)
        and the checkpoint it starts from (:meth:`check_checkpoint`)."""
        check_data = getattr(self, "check_data", None)
        if check_data is not None and datamodule is not None:
            check_data(datamodule, stage)
        if checkpoint is not None:
            self.check_checkpoint(checkpoint, datamodule, where, stage)

    def in_own_dtype(self, fn: Callable[[Tensor], Tensor], x: Tensor) -> Tensor:
        """``fn`` applied to ``x`` cast to the parameters' dtype, returned in ``x``'s: a
        float32 checkpoint takes float64 states (``odeint``, scipy) and frames."""
        param = next(self.parameters(), None)
        if param is None or param.dtype == x.dtype or not x.is_floating_point():
            return fn(x)
        return fn(x.to(param.dtype)).to(x.dtype)

    def training_loss(self, batch: Any) -> dict[str, Tensor]:
        """``{"loss": scalar, <part>: scalar, …}`` of a training batch; parts are logged."""
        raise NotImplementedError

    def param_groups(self) -> list[dict[str, Any]]:
        """Parameter groups, each with its ``weight_decay``."""
        return [{"params": list(self.parameters()), "weight_decay": self.recipe["weight_decay"]}]

    # ------------------------------------------------------------------ optimiser

    def _polish_count(self) -> int:
        """This fit's polishing steps: ``polish_steps``, or half of a ``max_steps`` not
        larger."""
        polish, most = self.recipe["polish_steps"], self.trainer.max_steps
        return most // 2 if polish and most and 0 < most <= polish else polish

    def _total_steps(self) -> int:
        """The first optimiser's steps: ``max_steps`` (else the epochs' batches ×
        ``inner_steps``) less the polishing steps."""
        if self.trainer.max_steps and self.trainer.max_steps > 0:
            total = self.trainer.max_steps
        else:
            total = int(self.trainer.estimated_stepping_batches) * self.recipe["inner_steps"]
        return max(1, total - self._polish_count())

    @staticmethod
    def _lbfgs(params: list[Tensor], lr: float) -> torch.optim.LBFGS:
        """One iteration a step, with a whole line search, every step taken. torch's
        defaults would cripple both: ``max_eval`` (1.25 ``max_iter``) leaves a one-iteration
        step no evaluation for its line search, which then keeps the start whenever the
        first trial is no better; and its tolerances (a gradient of max 1e-7, a squared
        norm or a change of 1e-9) stop it at a trained field's objective of ~1e-6."""
        return torch.optim.LBFGS(
            params,
            lr=lr,
            max_iter=1,
            max_eval=1 + MAX_LINE_SEARCH,
            history_size=50,
            line_search_fn="strong_wolfe",
            tolerance_grad=0.0,
            tolerance_change=0.0,
        )

    def on_fit_start(self) -> None:
        self._full_batch = None  # gathered at the first polishing step, from this fit's data
        self._evaluations = []
        self.polish_stopped_at = None
        polish, most = self.recipe["polish_steps"], self.trainer.max_steps
        if polish and not (most and most > 0):
            raise ValueError(
                f"model.init_args.polish_steps={polish} needs trainer.max_steps: they are "
                "the last steps of max_steps"
            )
        if polish and most <= polish:
            rank_zero_warn(
                f"model.init_args.polish_steps={polish} is not less than trainer.max_steps="
                f"{most}: the last {most // 2} steps polish"
            )
        if polish and self.trainer.world_size > 1:
            raise ValueError("model.init_args.polish_steps needs one process (L-BFGS: full batch)")

    def configure_optimizers(self) -> Any:
        r = self.recipe
        groups = self.param_groups()
        params = [p for g in groups for p in g["params"]]
        if r["optimizer"] == "lbfgs":
            opt = self._lbfgs(params, r["lr"])
        else:
            cls = torch.optim.AdamW if r["optimizer"] == "adamw" else torch.optim.Adam
            opt = cls(groups, lr=r["lr"])
        first = self._first_optimizer(opt)
        if not r["polish_steps"]:
            return first
        return [first, {"optimizer": self._lbfgs(params, 1.0)}]

    def _first_optimizer(self, opt: torch.optim.Optimizer) -> dict[str, Any]:
        """``opt`` with its schedule (:class:`RecipeModel`), as Lightning takes them."""
        r = self.recipe
        warm = r["warmup_steps"]
        if r["schedule"] == "constant" and not warm:
            return {"optimizer": opt}
        total = self._total_steps()
        if r["schedule"] == "onecycle":
            sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=r["lr"], total_steps=total + 1)
        else:
            cosine = r["schedule"] == "cosine"

            def factor(s: int) -> float:
                f = min(1.0, (s + 1) / warm) if warm else 1.0
                return f * (0.5 * (1 + math.cos(math.pi * min(s, total) / total)) if cosine else 1)

            sched = torch.optim.lr_scheduler.LambdaLR(opt, factor)
        return {"optimizer": opt, "lr_scheduler": sched}

    # ------------------------------------------------------------------ the loop

    def _l2(self, groups: list[dict[str, Any]]) -> Tensor | float:
        """``Σ_g λ_g/2 ‖θ_g‖²``: L-BFGS's weight decay, as a loss term."""
        return sum(
            g["weight_decay"] / 2 * sum(p.pow(2).sum() for p in g["params"])
            for g in groups
            if g["weight_decay"]
        )

    def _finite_gradients(self) -> bool:
        """Whether every parameter's gradient is finite (one max-abs per parameter)."""
        grads = [p.grad.detach() for p in self.parameters() if p.grad is not None]
        peaks = [g.abs().max() for g in grads if g.numel()]
        return not peaks or bool(torch.stack(peaks).isfinite().all())

    def _nonfinite(
        self, parts: dict[str, Tensor], can_skip: bool = True, gradients: bool = False
    ) -> bool:
        """Whether to skip this step: its loss is not finite (or, ``gradients``, a
        gradient of it is not); raises for ``on_nonfinite="stop"``."""
        loss_ok = bool(torch.isfinite(parts["loss"]))
        if loss_ok and (not gradients or self._finite_gradients()):
            self._skipped = 0
            return False
        skip = can_skip and self.recipe["on_nonfinite"] == "skip"
        if skip and self._skipped < MAX_SKIPS:
            self._skipped += 1
            return True
        ckpt = getattr(self.trainer.checkpoint_callback, "last_model_path", "") or "none"
        after = f" after {MAX_SKIPS} skipped steps" if skip else ""
        what = "training loss" if not loss_ok else "gradient of the training loss"
        raise FloatingPointError(
            f"non-finite {what} ({float(parts['loss'].detach())}) at step {self.global_step}"
            f"{after}: training stopped before the update (last good checkpoint: {ckpt}). "
            "Lower model.init_args.lr, set model.init_args.grad_clip, or on_nonfinite: skip."
        )

    def _lbfgs_step(
        self, opt: Any, batch: Any, groups: list[dict[str, Any]], polishing: bool = False
    ) -> dict[str, Tensor]:
        """One L-BFGS iteration on ``batch``, weight decay as the loss term :meth:`_l2`
        of ``groups``; ``polishing``: the objective in its squared form. A non-finite
        loss or gradient always stops."""
        parts: dict[str, Tensor] = {}
        params = [p for g in opt.param_groups for p in g["params"]]
        opening = polishing  # only a step's opening evaluation can repeat a kept one

        def closure() -> Tensor:
            nonlocal parts, opening
            if opening:
                opening = False
                seen = self._seen_evaluation(params)
                if seen is not None:
                    parts, loss = seen
                    return loss
            opt.zero_grad()
            self.polishing = polishing
            try:
                parts = self.training_loss(batch)
            finally:
                self.polishing = False
            self._nonfinite(parts, can_skip=False)
            loss = parts["loss"] + self._l2(groups)
            self.manual_backward(loss)
            self._nonfinite(parts, can_skip=False, gradients=True)
            if polishing:
                self._remember_evaluation(params, parts, loss)
            return loss

        opt.step(closure)
        return parts

    def _remember_evaluation(
        self, params: list[Tensor], parts: dict[str, Tensor], loss: Tensor
    ) -> None:
        """Keep a polishing evaluation — weights, objective, gradients — for
        :meth:`_seen_evaluation`; the last :data:`KEPT_EVALUATIONS` are kept (a line
        search mostly ends on its last trial, or on the one before)."""
        weights = torch.cat([p.detach().reshape(-1) for p in params])
        grads = [None if p.grad is None else p.grad.detach().clone() for p in params]
        detached = {k: v.detach() for k, v in parts.items()}
        self._evaluations = [
            *self._evaluations[1 - KEPT_EVALUATIONS :],
            (weights, detached, loss.detach(), grads),
        ]

    def _seen_evaluation(self, params: list[Tensor]) -> tuple[dict[str, Tensor], Tensor] | None:
        """The objective and gradients (set into ``.grad``) of a polishing evaluation at
        exactly these weights, if one was kept. torch's L-BFGS evaluates the objective at
        the start of every ``step`` although its previous line search ended on a point it
        evaluated (bit for bit the same weights: both are ``x + t·d`` from the same ``x``);
        with one iteration a step, that repeat is one evaluation in every iteration."""
        if not self._evaluations:
            return None
        weights = torch.cat([p.detach().reshape(-1) for p in params])
        for seen, parts, loss, grads in reversed(self._evaluations):
            if torch.equal(seen, weights):
                for p, g in zip(params, grads, strict=True):
                    p.grad = None if g is None else g.clone()
                return parts, loss
        return None

    def _polish_step(self, opt: Any) -> dict[str, Tensor]:
        """One L-BFGS iteration of the polishing (:class:`RecipeModel`) on the whole
        training set, the objective in its squared form, without weight decay."""
        if self._full_batch is None:
            rows = getattr(self.trainer.train_dataloader, "tensors", None)
            if rows is None:
                raise ValueError(
                    "model.init_args.polish_steps needs data that serve their rows in one "
                    "object (hnn_pl's DataModules do)"
                )
            self._full_batch = tuple(t.to(self.device) for t in rows)
        before = [p.detach().clone() for p in self.parameters()]
        parts = self._lbfgs_step(opt, self._full_batch, [], polishing=True)
        if all(torch.equal(a, p) for a, p in zip(before, self.parameters(), strict=True)):
            self._stop_polishing()
        return parts

    def _stop_polishing(self) -> None:
        """End the fit: the polishing step just taken left every weight as it was. Its
        line search found no lower objective along its direction (in this precision), and
        every later step would repeat it from the same point (no change, no new curvature
        pair, the same direction): the weights are final, the rest is lost time."""
        self.polish_stopped_at = self.global_step
        self.trainer.should_stop = True
        rank_zero_info(
            f"Polishing stopped at step {self.global_step} of {self.trainer.max_steps}: "
            "L-BFGS's line search found no lower objective, and every later step would "
            "repeat it (the weights are final)."
        )

    def training_step(self, batch: Any, batch_idx: int) -> None:
        opts, sched = self.optimizers(), self.lr_schedulers()
        opt, polisher = (opts[0], opts[1]) if isinstance(opts, list) else (opts, None)
        r = self.recipe
        steps = r["inner_steps"]
        if self.trainer.max_steps and self.trainer.max_steps > 0:
            steps = max(1, min(steps, self.trainer.max_steps - self.global_step))
        parts: dict[str, Tensor] = {}
        groups = self.param_groups() if r["optimizer"] == "lbfgs" else []
        for _ in range(steps):
            if polisher is not None and self.global_step >= self._total_steps():
                parts = self._polish_step(polisher)
                if self.polish_stopped_at is not None:
                    break
                continue
            if r["optimizer"] == "lbfgs":
                parts = self._lbfgs_step(opt, batch, groups)
            else:
                opt.zero_grad()
                parts = self.training_loss(batch)
                if self._nonfinite(parts):
                    continue
                self.manual_backward(parts["loss"])
                if self._nonfinite(parts, gradients=True):
                    continue
                if r["grad_clip"] is not None:
                    self.clip_gradients(opt, r["grad_clip"], "norm")
                opt.step()
            if sched is not None:
                sched.step()
        if parts:
            self.log("train/loss", parts["loss"].detach(), prog_bar=True)
            for name, value in parts.items():
                if name != "loss":
                    self.log(f"train/{name}", value.detach())
