"""The pixel pendulum's models: an autoencoder with latent dynamics (HNN or baseline).

The loss is the reference's (``pixelhnn_loss`` in ``experiment-pixels/train.py`` of
greydanus/hamiltonian-nn): ``ae_loss + cc_loss + 0.1·hnn_loss``, here ``recon``,
``canonical`` and ``latent`` (:class:`AutoencoderDynamicsModel`), with
``Adam(lr=1e-3, weight_decay=1e-5)``, batches of 200 and ``input_noise = 0``. Its
latent step is ``z + f(z)`` with **no ``dt``**: the latent time unit is *one frame*
(0.05 s). Here ``frame_dt`` (default 1.0, the reference) is a frame's length in the
field's time unit (``0.05``: seconds); the canonical term does not depend on it.
Every term is a mean over its own dimensions, then over the batch; nothing is
detached and only ``x_t`` is reconstructed. The reference's HNN MLP has two outputs
and uses the second as ``H``; one is enough (:class:`~hnn_pl.nets.HamiltonianField`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torchmetrics import MeanMetric

from hnn_pl.models.baseline import Baseline
from hnn_pl.models.hnn import HNN
from hnn_pl.models.recipe import RecipeModel, is_count, is_weight
from hnn_pl.nets import PixelDecoder, PixelEncoder

#: the loss terms, in the order they are logged (``train/<name>``, ``val/<name>``, …)
LOSS_PARTS = ("loss", "recon", "canonical", "latent")


class AutoencoderDynamicsModel(RecipeModel):
    """Autoencoder ``x ↦ z ↦ x̂`` with a latent vector field ``dz/dt = f_θ(z)``.

    Subclasses implement :meth:`build_field`. Batches are ``(x_t, x_{t+1})``, each
    ``(batch, input_dim)``. With ``z = E(x_t) = (q, p)``, ``z' = E(x_{t+1})``, the
    loss is ``recon_weight·recon + canonical_weight·canonical + hnn_weight·latent``::

        recon     = mean (x_t − D(z))²
        canonical = mean (p − (q' − q))²
        latent    = mean (z' − (z + frame_dt·f_θ(z + ε)))²     ε ~ N(0, input_noise²)

    (``ε`` only in training). Logs ``train/<part>`` (the parts unweighted) every step
    and ``val/…``, ``test/…`` as batch-size-weighted means over the split.

    Args:
        input_dim: length of an input, ``2·28² = 1568`` (linked from the DataModule).
        hidden_dim: width of the autoencoder's hidden layers (200).
        latent_dim: ``2k``, the latent size (2); must be even.
        ae_activation: the autoencoder's nonlinearity (``"relu"``, reference).
        field_hidden_dim, field_n_hidden: the latent field MLP's width and depth (200, 2).
        field_activation: its nonlinearity (``"tanh"``: a closed-form ``∇H``).
        recon_weight, canonical_weight, hnn_weight: loss weights (1, 1, 0.1).
        frame_dt: one frame in the latent field's time unit (1.0: the reference).
        input_noise: std of the training noise ``ε`` (reference ``--input_noise``, 0).
        weight_decay: the L2 coefficient; the reference's 1e-5 where the recipe's default
            is 0 (the one recipe option whose default differs here).
        field_weight_decay: the latent field's (``None``: ``weight_decay``, the reference;
            Adam's L2 can pin an early, small field at zero, see ``configs/pixel.yaml``).
        **kwargs: the rest of the training recipe (:class:`~hnn_pl.models.recipe.RecipeModel`:
            ``lr``, ``optimizer``, ``schedule``, …).
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
        weight_decay: float = 1e-5,
        field_weight_decay: float | None = None,
        **kwargs,
    ) -> None:
        super().__init__(weight_decay=weight_decay, **kwargs)
        if not is_count(latent_dim, 2) or latent_dim % 2:
            raise ValueError(f"latent_dim must be even and >= 2 (z = (q, p)), got {latent_dim}")
        counts = dict(
            input_dim=input_dim,
            hidden_dim=hidden_dim,
            field_hidden_dim=field_hidden_dim,
            field_n_hidden=field_n_hidden,
        )
        weights = dict(
            recon_weight=recon_weight,
            canonical_weight=canonical_weight,
            hnn_weight=hnn_weight,
            input_noise=input_noise,
            field_weight_decay=0.0 if field_weight_decay is None else field_weight_decay,
        )
        for name, value in counts.items():
            if not is_count(value):
                raise ValueError(f"{name} must be an integer >= 1: {value}")
        for name, value in weights.items():
            if not is_weight(value):
                raise ValueError(f"{name} must be finite and >= 0: {value}")
        if not (is_weight(frame_dt) and frame_dt > 0):
            raise ValueError(f"frame_dt must be finite and > 0: {frame_dt}")
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

    def encode(self, x: Tensor) -> Tensor:
        """``x (..., input_dim) -> z (..., latent_dim)``, in ``x``'s dtype (evaluated in
        the model's)."""
        return self.in_own_dtype(self.encoder, x)

    forward = encode

    def decode(self, z: Tensor) -> Tensor:
        """``z (..., latent_dim) -> x̂ (..., input_dim)``, in ``z``'s dtype (evaluated in
        the model's)."""
        return self.in_own_dtype(self.decoder, z)

    def vector_field(self, t: Tensor | float | None, z: Tensor) -> Tensor:
        """The latent ``f_θ(t, z)``, ``(batch, latent_dim) -> (batch, latent_dim)``, in
        ``z``'s dtype (evaluated in the model's)."""
        return self.in_own_dtype(lambda z: self.field.vector_field(t, z), z)

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

    @property
    def frame_dt(self) -> float:
        """One frame in the latent field's time unit."""
        return float(self.hparams.frame_dt)

    def rollout(
        self, x0: Tensor, n_frames: int, method: str = "dopri5", dtype="float64", **kwargs
    ) -> tuple[Tensor, Tensor]:
        """Encode ``x0 (B, input_dim)``, integrate over ``n_frames`` frames
        (``t = k·frame_dt``) and decode (see :func:`hnn_pl.rollout`): ``z (n_frames, B,
        latent_dim)`` in the integration dtype, ``x̂ (n_frames, B, input_dim)`` in the
        model's."""
        from hnn_pl.evaluation import rollout

        t = torch.arange(n_frames, dtype=torch.float64, device=x0.device) * self.frame_dt
        out = rollout(self, x0, t, method=method, dtype=dtype, **kwargs)
        return out.z_pred, out.x_pred

    # ------------------------------------------------------------------ Lightning

    def training_loss(self, batch: tuple[Tensor, Tensor]) -> dict[str, Tensor]:
        return self.losses(*batch[:2], noise=True)

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

    def param_groups(self) -> list[dict]:
        """The latent field with ``field_weight_decay``, the autoencoder with ``weight_decay``."""
        hp = self.hparams
        field = list(self.field.parameters())
        ids = {id(p) for p in field}
        rest = [p for p in self.parameters() if id(p) not in ids]
        field_wd = hp.weight_decay if hp.field_weight_decay is None else hp.field_weight_decay
        return [
            {"params": rest, "weight_decay": hp.weight_decay},
            {"params": field, "weight_decay": field_wd},
        ]


class AutoencoderHNN(AutoencoderDynamicsModel):
    """Latent HNN: ``dz/dt = J∇H_θ(z)``, ``H_θ = MLP(z): 2 → 200 → 200 → 1`` (tanh,
    closed-form ``∇H_θ``), with ``hamiltonian(z)``. Arguments as the base class."""

    build_field = HNN.build_field
    hamiltonian = HNN.hamiltonian


class AutoencoderBaseline(AutoencoderDynamicsModel):
    """Latent baseline: ``dz/dt = MLP(z): 2 → 200 → 200 → 2`` (tanh, no output bias).
    Arguments as the base class."""

    build_field = Baseline.build_field
