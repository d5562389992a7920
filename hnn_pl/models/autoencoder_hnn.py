"""The pixel pendulum's models: an autoencoder with latent dynamics (HNN or baseline).

The reference (``experiment-pixels/train.py`` of greydanus/hamiltonian-nn, the
version with per-sample losses)::

    def pixelhnn_loss(x, x_next, model, return_scalar=True):
      z = model.encode(x)
      z_next = model.encode(x_next)
      x_hat = model.decode(z)
      ae_loss = ((x - x_hat)**2).mean(1)
      noise = args.input_noise * torch.randn(*z.shape)
      z_hat_next = z + model.time_derivative(z + noise) # replace with rk4
      hnn_loss = ((z_next - z_hat_next)**2).mean(1)
      w, dw = z.split(1,1)
      w_next, _ = z_next.split(1,1)
      cc_loss = ((dw-(w_next - w))**2).mean(1)
      loss = ae_loss + cc_loss + 1e-1 * hnn_loss

with ``Adam(lr=1e-3, weight_decay=1e-5)``, batches of 200 drawn with
``torch.randperm`` every step, ``input_noise = 0``, and the latent field
``PixelHNN.time_derivative`` (an HNN ``J∇H`` on ``MLP(2, 200, 2)``, tanh, or for
``--baseline`` the MLP's output itself). Notes:

- **No ``dt``**: the field is added to ``z`` as is, so the latent time unit is
  *one frame* (0.05 s). Here ``frame_dt`` (default 1.0, the reference) is the
  length of a frame in the field's time unit: the HNN loss is
  ``z_{t+1} − (z_t + frame_dt·f(z_t))`` and rollouts integrate to
  ``t = k·frame_dt``. ``frame_dt = 0.05`` measures latent time in seconds.
- Every term is a mean over its own dimensions (1568 pixels, 1 for the canonical
  term, 2 latents) and then over the batch, as here.
- Gradients flow through both ``z`` and ``z_next`` (nothing is detached); only
  ``x`` (not ``x_next``) is reconstructed; the reference's old version
  (``utils.L2_loss``, a plain mean over everything) gives the same numbers.
- The canonical term is independent of ``frame_dt``: ``p_t ≈ q_{t+1} − q_t``.
- The reference's HNN MLP has two outputs and uses the second as ``H``; one is
  enough (:class:`~hnn_pl.nets.HamiltonianField`).
"""

from __future__ import annotations

import lightning as L
import torch
from torch import Tensor, nn
from torchmetrics import MeanMetric

from hnn_pl.nets import MLP, DirectField, HamiltonianField, PixelDecoder, PixelEncoder
from hnn_pl.rollout import integrate_field

#: the loss terms, in the order they are logged (``train/<name>``, ``val/<name>``, …)
LOSS_PARTS = ("loss", "recon", "canonical", "latent")


class AutoencoderDynamicsModel(L.LightningModule):
    """Autoencoder ``x ↦ z ↦ x̂`` with a latent vector field ``dz/dt = f_θ(z)``.

    Subclasses implement :meth:`build_field` (the latent field, with
    ``vector_field(t, z)``). Batches are ``(x_t, x_{t+1})``: consecutive inputs
    (pairs of frames, ``(batch, input_dim)`` each). With ``z = E(x_t)``,
    ``z' = E(x_{t+1})`` and ``z = (q, p)`` split in halves, the loss is
    ``recon_weight·recon + canonical_weight·canonical + hnn_weight·latent``::

        recon     = mean (x_t − D(z))²
        canonical = mean (p − (q' − q))²
        latent    = mean (z' − (z + frame_dt·f_θ(z + ε)))²     ε ~ N(0, input_noise²)

    (``latent`` is the reference's "HNN loss", for the baseline too; ``ε`` only in
    training). Logs ``train/loss`` and its unweighted parts ``train/recon``,
    ``train/canonical``, ``train/latent`` every step, and ``val/…``, ``test/…``
    (the same four) as means over the whole split (torchmetrics
    ``MeanMetric``, weighted by batch size, so they equal the loss of the split
    as one batch).

    Args:
        input_dim: length of an input, ``2·28² = 1568`` (linked from the
            DataModule's ``state_dim`` by the CLI).
        hidden_dim: width of the autoencoder's hidden layers (200).
        latent_dim: ``2k``, the latent size (2); must be even.
        ae_activation: the autoencoder's nonlinearity (``"relu"``, reference).
        field_hidden_dim: width of the latent field's MLP (200).
        field_n_hidden: its hidden layers (2).
        field_activation: its nonlinearity (``"tanh"``; the HNN then has a
            closed-form ``∇H``).
        recon_weight, canonical_weight, hnn_weight: loss weights (1, 1, 0.1).
        frame_dt: one frame in the latent field's time unit (1.0: the reference).
        input_noise: std of the noise added to ``z`` before the field, in training
            (reference flag ``--input_noise``, default 0).
        lr: Adam learning rate (1e-3).
        weight_decay: Adam weight decay (1e-5), an L2 term added to the gradient as
            ``torch.optim.Adam`` (and the reference) does.
        field_weight_decay: the latent field's weight decay (``None``: ``weight_decay``,
            the reference). Adam normalises the L2 term like any gradient, so a
            weight whose loss gradient is far below ``weight_decay·|w|`` shrinks by
            about ``lr`` per step: a field pushed towards zero early in training
            (when the encoder does not yet separate frames, ``z_{t+1} ≈ z_t``) can be
            driven to exactly zero, a saddle it never leaves (see the configs).
    """

    def __init__(
        self,
        input_dim: int = 1568,
        hidden_dim: int = 200,
        latent_dim: int = 2,
        ae_activation: str = "relu",
        field_hidden_dim: int = 200,
        field_n_hidden: int = 2,
        field_activation: str = "tanh",
        recon_weight: float = 1.0,
        canonical_weight: float = 1.0,
        hnn_weight: float = 0.1,
        frame_dt: float = 1.0,
        input_noise: float = 0.0,
        lr: float = 1e-3,
        weight_decay: float = 1e-5,
        field_weight_decay: float | None = None,
    ) -> None:
        super().__init__()
        if latent_dim < 2 or latent_dim % 2:
            raise ValueError(f"latent_dim must be even and >= 2 (z = (q, p)), got {latent_dim}")
        self.save_hyperparameters()
        self.encoder = PixelEncoder(input_dim, hidden_dim, latent_dim, ae_activation)
        self.decoder = PixelDecoder(latent_dim, hidden_dim, input_dim, ae_activation)
        self.field = self.build_field(
            latent_dim, field_hidden_dim, field_n_hidden, field_activation
        )
        self.val_metrics = nn.ModuleDict({k: MeanMetric() for k in LOSS_PARTS})
        self.test_metrics = nn.ModuleDict({k: MeanMetric() for k in LOSS_PARTS})

    def build_field(
        self, latent_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> nn.Module:
        """The latent field: a plain module with ``vector_field(t, z)``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the model

    def encode(self, x: Tensor) -> Tensor:
        """``x (..., input_dim) -> z (..., latent_dim)``."""
        return self.encoder(x)

    def decode(self, z: Tensor) -> Tensor:
        """``z (..., latent_dim) -> x̂ (..., input_dim)``."""
        return self.decoder(z)

    def vector_field(self, t: Tensor | float | None, z: Tensor) -> Tensor:
        """The latent ``f_θ(t, z)``, ``(batch, latent_dim) -> (batch, latent_dim)``, in
        the time unit in which a frame lasts ``frame_dt``."""
        return self.field.vector_field(t, z)

    def forward(self, x: Tensor) -> Tensor:
        """The latent code ``E(x)``."""
        return self.encoder(x)

    def losses(self, x: Tensor, x_next: Tensor, noise: bool = False) -> dict[str, Tensor]:
        """The weighted total ``loss`` and its unweighted parts ``recon``,
        ``canonical``, ``latent`` (scalars) of a batch of consecutive inputs."""
        hp = self.hparams
        z, z_next = self.encoder(x), self.encoder(x_next)
        recon = (x - self.decoder(z)).pow(2).mean()
        k = z.shape[-1] // 2
        q, p, q_next = z[..., :k], z[..., k:], z_next[..., :k]
        canonical = (p - (q_next - q)).pow(2).mean()
        z_in = z + hp.input_noise * torch.randn_like(z) if noise and hp.input_noise else z
        z_hat = z + hp.frame_dt * self.field.vector_field(None, z_in)
        latent = (z_next - z_hat).pow(2).mean()
        loss = hp.recon_weight * recon + hp.canonical_weight * canonical + hp.hnn_weight * latent
        return {"loss": loss, "recon": recon, "canonical": canonical, "latent": latent}

    def rollout(
        self,
        x0: Tensor,
        n_frames: int,
        method: str = "dopri5",
        dtype: torch.dtype | None = torch.float64,
        **kwargs,
    ) -> tuple[Tensor, Tensor]:
        """Encode ``x0 (B, input_dim)``, integrate the latent field over ``n_frames``
        frames (``t = k·frame_dt``, ``k = 0 … n_frames − 1``) and decode.

        ``dtype``: integrate a copy of the field in this dtype (float64 default;
        ``None``: the model's); ``kwargs`` go to :func:`hnn_pl.odeint`. Runs
        without recording gradients.

        Returns:
            ``z (n_frames, B, latent_dim)`` in the integration dtype and the decoded
            ``x̂ (n_frames, B, input_dim)`` in the model's.
        """
        with torch.no_grad():
            z0 = self.encode(x0)
            t = torch.arange(n_frames, dtype=torch.float64) * self.hparams.frame_dt
            z, _ = integrate_field(self.field, z0, t.to(z0.device), method, dtype, **kwargs)
            return z, self.decode(z.to(z0.dtype))

    # ------------------------------------------------------------------ Lightning

    def training_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> Tensor:
        parts = self.losses(*batch[:2], noise=True)
        self.log("train/loss", parts["loss"], prog_bar=True)
        for name in LOSS_PARTS[1:]:
            self.log(f"train/{name}", parts[name])
        return parts["loss"]

    def _eval_step(self, batch: tuple[Tensor, Tensor], metrics: nn.ModuleDict, split: str):
        x, x_next = batch[:2]
        parts = self.losses(x, x_next)
        for name in LOSS_PARTS:
            metrics[name].update(parts[name], weight=x.shape[0])
            self.log(f"{split}/{name}", metrics[name], prog_bar=name == "loss" and split == "val")

    def validation_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> None:
        self._eval_step(batch, self.val_metrics, "val")

    def test_step(self, batch: tuple[Tensor, Tensor], batch_idx: int) -> None:
        self._eval_step(batch, self.test_metrics, "test")

    def predict_step(self, batch: tuple[Tensor, ...], batch_idx: int) -> Tensor:
        """The latent codes of the batch's inputs, ``(batch, latent_dim)``."""
        return self.encoder(batch[0])

    def configure_optimizers(self) -> torch.optim.Optimizer:
        hp = self.hparams
        field = list(self.field.parameters())
        ids = {id(p) for p in field}
        rest = [p for p in self.parameters() if id(p) not in ids]
        field_wd = hp.weight_decay if hp.field_weight_decay is None else hp.field_weight_decay
        groups = [
            {"params": rest, "weight_decay": hp.weight_decay},
            {"params": field, "weight_decay": field_wd},
        ]
        return torch.optim.Adam(groups, lr=hp.lr)


class AutoencoderHNN(AutoencoderDynamicsModel):
    """Latent HNN: ``dz/dt = J∇H_θ(z)``, ``H_θ = MLP(z): 2 → 200 → 200 → 1`` (tanh).

    For the tanh MLP ``∇H_θ`` is computed in closed form (one ordinary backward pass
    in training; rollouts and evaluation work under ``torch.inference_mode``).
    Arguments as :class:`AutoencoderDynamicsModel`.
    """

    def build_field(
        self, latent_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> HamiltonianField:
        return HamiltonianField(MLP(latent_dim, 1, hidden_dim, n_hidden, activation))

    def hamiltonian(self, z: Tensor) -> Tensor:
        """The learned ``H_θ(z)``: ``(batch, latent_dim) -> (batch,)``."""
        return self.field.hamiltonian(z)


class AutoencoderBaseline(AutoencoderDynamicsModel):
    """Latent baseline: ``dz/dt = MLP(z): 2 → 200 → 200 → 2`` (tanh, no output bias).

    Arguments as :class:`AutoencoderDynamicsModel`.
    """

    def build_field(
        self, latent_dim: int, hidden_dim: int, n_hidden: int, activation: str
    ) -> DirectField:
        return DirectField(MLP(latent_dim, latent_dim, hidden_dim, n_hidden, activation))
