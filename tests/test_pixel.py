"""Pixel pendulum: DataModule, autoencoder models, latent rollout callback, CLI."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from hnn_pl import evaluation, plotting
from hnn_pl.commands.cli import cli_main
from hnn_pl.data.pixel import PixelPendulumData
from hnn_pl.evaluation import Rollout, apply_probe, fit_probe
from hnn_pl.models import AutoencoderBaseline, AutoencoderHNN
from hnn_pl.render import render_pendulum

#: a tiny data set: 6 trajectories × 8 frames (5 samples each), 2 held out, rollouts of 12
TINY = dict(n_trajectories=6, n_frames=8, rollout_frames=12, test_fraction=1 / 3)
PIX = 28 * 28


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _data(tmp_path: Path, **kwargs) -> PixelPendulumData:
    dm = PixelPendulumData(**{**TINY, "cache_dir": str(tmp_path / "cache"), **kwargs})
    dm.setup()
    return dm


# --------------------------------------------------------------------------- data


def test_shapes_ranges_and_split(tmp_path):
    dm = _data(tmp_path)
    assert dm.state_dim == 1568
    assert dm.n_test == 2
    n_train, n_test = 4 * 5, 2 * 5  # n_frames − 3 samples per trajectory
    for split, n in (("train", n_train), ("test", n_test)):
        assert getattr(dm, f"x_{split}").shape == (n, 1568)
        assert getattr(dm, f"dx_{split}").shape == (n, 1568)
        assert getattr(dm, f"y_{split}").shape == (n, 2)
    assert dm.x_train.dtype == torch.float32
    assert dm.test_t.shape == (12,) and dm.test_y.shape == (12, 2, 2)
    assert dm.rollout_x.shape == (12, 2, 1568)
    torch.testing.assert_close(dm.test_t, torch.arange(12) * 0.05)
    for x in (dm.x_train, dm.dx_train, dm.x_test, dm.rollout_x):
        assert float(x.min()) == 0.0 and 0.45 < float(x.max()) <= 128 / 255 + 1e-7
    # every frame shows the rod: a few pixels' worth of intensity, well below a full frame
    mass = dm.x_train.view(-1, 2, PIX).sum(-1)
    assert bool((mass > 10).all()) and bool((mass < 100).all())
    # starts within the bounds; the small swings never leave ±(π/6 + a little)
    assert float(dm.theta[:, 0].abs().max()) < math.pi / 6
    assert float(dm.omega[:, 0].abs().max()) < 1.0
    assert float(dm.theta.abs().max()) < 0.8
    # batches are (x_t, x_{t+1}) pairs of 200 (or fewer) rows
    x, x_next = next(iter(dm.train_dataloader()))
    assert x.shape == x_next.shape == (n_train, 1568)  # batch 200 > 20 rows


def test_default_sizes_match_the_reference(tmp_path):
    dm = PixelPendulumData(cache_dir=str(tmp_path / "cache"))
    assert (dm.n_trajectories, dm.n_frames, dm.rollout_frames, dm.n_test) == (200, 103, 200, 40)
    assert dm.batch_size == 200 and dm.state_dim == 1568
    # 100 samples per trajectory: train 160 × 100 = 16k, test 40 × 100 = 4k (first 20 %)
    assert (dm.n_trajectories - dm.n_test) * (dm.n_frames - 3) == 16_000


def test_generation_is_deterministic_cached_and_seeded(tmp_path, monkeypatch):
    a = _data(tmp_path)
    assert a.cache_path.exists()
    assert a.cache_path.stat().st_size < 100_000  # angles only, frames are rendered

    def boom(self):
        raise AssertionError("generate() called although the cache holds the data")

    # a context of its own: ``monkeypatch.undo()`` would also undo conftest's removal of
    # PL_GLOBAL_SEED, and a seed left in the environment would then seed ``d`` below
    with monkeypatch.context() as m:
        m.setattr(PixelPendulumData, "generate", boom)
        b = _data(tmp_path)
    for key in ("x_train", "dx_train", "y_train", "x_test", "test_y", "rollout_x"):
        assert torch.equal(getattr(a, key), getattr(b, key)), key
    c = _data(tmp_path, seed=1)
    assert c.cache_path != a.cache_path
    assert not torch.equal(a.y_train, c.y_train)
    # frames are rendered from the float64 angles whatever the served dtype
    d = _data(tmp_path, dtype="float64")
    assert d.x_train.dtype == torch.float64
    torch.testing.assert_close(d.x_train.float(), a.x_train, rtol=0, atol=0)


def test_states_follow_the_gym_map_and_label_the_second_frame(tmp_path):
    dm = _data(tmp_path)
    th, om = dm.theta, dm.omega  # (6, 8) float64
    # gym Pendulum-v0, no torque: ω' = ω − (3g/2l) sin θ dt, θ' = θ + ω' dt (g = 10, l = 1)
    om_next = om[:, :-1] - 15.0 * torch.sin(th[:, :-1]) * 0.05
    torch.testing.assert_close(om[:, 1:], om_next, rtol=0, atol=1e-12)
    torch.testing.assert_close(th[:, 1:], th[:, :-1] + om_next * 0.05, rtol=0, atol=1e-12)
    # sample j of trajectory i (train = trajectories 2..5) is the pair (frame j+1, frame j+2),
    # labelled with the state of frame j + 2
    y = dm.y_train.view(4, 5, 2).double()
    torch.testing.assert_close(y[..., 0], th[2:, 2:7], rtol=0, atol=1e-6)
    torch.testing.assert_close(y[..., 1], om[2:, 2:7], rtol=0, atol=1e-6)
    # ... and the second frame of the pair is the rendering of that state's angle
    # (the data module renders in float32: within 1e-5 of a float64 rendering)
    second = dm.x_train[:, PIX:]
    drawn = render_pendulum(dm.theta[2:, 2:7].reshape(-1)).reshape(-1, PIX).float()
    torch.testing.assert_close(second, drawn, rtol=0, atol=1e-5)
    first = dm.x_train[:, :PIX]
    drawn = render_pendulum(dm.theta[2:, 1:6].reshape(-1)).reshape(-1, PIX).float()
    torch.testing.assert_close(first, drawn, rtol=0, atol=1e-5)
    # the held-out trajectories are the first ones, continued for the rollouts
    torch.testing.assert_close(dm.rollout_theta[:, :8], th[:2], rtol=0, atol=0)
    torch.testing.assert_close(dm.test_y[:, :, 0].T.double(), dm.rollout_theta[:, 1:13])


def test_next_input_is_the_input_shifted_by_one_frame(tmp_path):
    dm = _data(tmp_path)
    for x, nx in ((dm.x_train, dm.dx_train), (dm.x_test, dm.dx_test)):
        assert torch.equal(x[:, PIX:], nx[:, :PIX])  # second frame of x_t = first of x_{t+1}
        assert not torch.equal(x[:, :PIX], nx[:, :PIX])
        # within a trajectory the next input is the next row
        rows = x.view(-1, 5, 1568)
        assert torch.equal(nx.view(-1, 5, 1568)[:, :-1], rows[:, 1:])
    # rollout pairs: P_k = (frame k, frame k+1), the test split holds P_1 … P_5
    assert torch.equal(dm.rollout_x[1:, :, :PIX], dm.rollout_x[:-1, :, PIX:])
    assert torch.equal(dm.rollout_x[1:6].transpose(0, 1).reshape(-1, 1568), dm.x_test)


def test_rollout_truth_extends_beyond_the_stored_horizon(tmp_path):
    dm = _data(tmp_path)
    t, y = dm.rollout_target()
    assert torch.equal(t, dm.test_t) and torch.equal(y, dm.test_y)
    t, y, x = dm.rollout_truth(n_points=20)
    assert t.shape == (20,) and y.shape == (20, 2, 2) and x.shape == (20, 2, 1568)
    assert torch.equal(x[:12], dm.rollout_x) and torch.equal(y[:12], dm.test_y)
    torch.testing.assert_close(t, torch.arange(20) * 0.05)
    assert dm.rollout_truth(t_end=0.5)[0].shape == (11,)
    # energy: α(1 − cos θ) + (θ̇/4)², α = 1.875
    e = dm.energy(dm.test_y)
    q, p = dm.test_y[..., 0], 0.25 * dm.test_y[..., 1]
    torch.testing.assert_close(e, 1.875 * (1 - torch.cos(q)) + p**2)
    with pytest.raises(ValueError, match="holds out 0"):
        PixelPendulumData(n_trajectories=2, test_fraction=0.1)


def test_trajectory_truth_is_a_fresh_trajectory_without_its_first_frame(tmp_path):
    """The reference's test trajectory: gym's map from (θ₀, θ̇₀), frame 0 dropped."""
    dm = _data(tmp_path)
    t, y, x = dm.trajectory_truth(0.2934, 0.7326, 10)
    assert t.shape == (10,) and y.shape == (10, 1, 2) and x.shape == (10, 1, 1568)
    th, om = 0.2934, 0.7326
    states = []
    for _ in range(11):
        om = om - 15.0 * math.sin(th) * 0.05
        th = th + om * 0.05
        states.append((th, om))
    # pair k = frames k + 1, k + 2, labelled with the state of frame k + 2
    expected = torch.tensor(states[1:], dtype=torch.float64)
    torch.testing.assert_close(y[:, 0].double(), expected, rtol=0, atol=1e-6)
    angles = torch.tensor([s[0] for s in states], dtype=torch.float64)
    frames = render_pendulum(angles).reshape(11, PIX).float()
    torch.testing.assert_close(x[:, 0, :PIX], frames[:10], rtol=0, atol=1e-5)
    torch.testing.assert_close(x[:, 0, PIX:], frames[1:], rtol=0, atol=1e-5)
    assert dm.trajectory_truth(0.2934, 0.7326, 10)[2] is x  # made once
    # the energy the reference scored: α = 1.9 on request, the system's 1.875 otherwise
    qp = dm.canonical(y)
    torch.testing.assert_close(
        dm.canonical_energy(qp, 1.9), 1.9 * (1 - torch.cos(qp[..., 0])) + qp[..., 1] ** 2
    )
    torch.testing.assert_close(dm.canonical_energy(qp), dm.energy(y))


def test_pixel_protocol_fields_are_checked():
    ref = evaluation.task_protocol("pixel", "reference")
    assert ref.start == (0.2934, 0.7326) and ref.model_t_end == pytest.approx(196.0)
    assert ref.energy_coef == 1.9 and ref.reencode and ref.probe_encoder == "hnn"
    assert ref.replace(start=[0.1, 0.2]).start == (0.1, 0.2)
    with pytest.raises(ValueError, match="reencode"):
        ref.replace(reencode=False)
    with pytest.raises(ValueError, match="probe_encoder"):
        ref.replace(probe_encoder="baseline")
    with pytest.raises(ValueError, match="start"):
        ref.replace(start=(0.1,))
    with pytest.raises(ValueError, match="model_t_end"):
        ref.replace(model_t_end=0.0)


# --------------------------------------------------------------------------- models


def test_latent_hnn_field_is_J_grad_H_by_autograd():
    torch.manual_seed(0)
    model = AutoencoderHNN(input_dim=1568).double()
    z = torch.randn(16, 2, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(model.hamiltonian(z).sum(), z)
    expected = torch.stack([grad[:, 1], -grad[:, 0]], -1)
    torch.testing.assert_close(model.vector_field(None, z), expected, rtol=1e-10, atol=1e-12)
    with torch.inference_mode():  # closed form: no autograd needed
        out = model.vector_field(None, z.detach())
    torch.testing.assert_close(out, expected, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("cls", [AutoencoderHNN, AutoencoderBaseline])
def test_loss_is_recon_plus_canonical_plus_weighted_one_frame_euler_step(cls):
    torch.manual_seed(0)
    model = cls(input_dim=50, hidden_dim=16, field_hidden_dim=16, frame_dt=0.5)
    model.hparams.update(recon_weight=2.0, canonical_weight=3.0, hnn_weight=0.25)
    x, x_next = torch.rand(7, 50), torch.rand(7, 50)
    parts = model.losses(x, x_next)
    z, zn = model.encode(x), model.encode(x_next)
    recon = ((x - model.decode(z)) ** 2).mean()
    canonical = ((z[:, 1] - (zn[:, 0] - z[:, 0])) ** 2).mean()
    latent = ((zn - z - 0.5 * model.vector_field(None, z)) ** 2).mean()
    torch.testing.assert_close(parts["recon"], recon)
    torch.testing.assert_close(parts["canonical"], canonical)
    torch.testing.assert_close(parts["latent"], latent)
    torch.testing.assert_close(parts["loss"], 2 * recon + 3 * canonical + 0.25 * latent)
    assert hasattr(model, "hamiltonian") == (cls is AutoencoderHNN)
    # gradients reach the encoder, the decoder and the field
    parts["loss"].backward()
    for name in ("encoder.linear1.weight", "decoder.linear8.weight", "field.net.out.weight"):
        assert float(dict(model.named_parameters())[name].grad.abs().sum()) > 0, name


def test_field_weight_decay_is_its_own_parameter_group():
    small = dict(input_dim=50, hidden_dim=8, field_hidden_dim=8)
    model = AutoencoderHNN(**small, field_weight_decay=0.0)
    ae, field = model.configure_optimizers()["optimizer"].param_groups
    assert ae["weight_decay"] == 1e-5 and field["weight_decay"] == 0.0 and field["lr"] == 1e-3
    assert {id(p) for p in field["params"]} == {id(p) for p in model.field.parameters()}
    assert len(ae["params"]) + len(field["params"]) == len(list(model.parameters()))
    default = AutoencoderBaseline(**small).configure_optimizers()["optimizer"]
    assert [g["weight_decay"] for g in default.param_groups] == [1e-5, 1e-5]


def test_probe_recovers_an_affine_map():
    g = torch.Generator().manual_seed(0)
    z = torch.randn(100, 2, generator=g, dtype=torch.float64)
    w = torch.tensor([[0.5, -1.0], [2.0, 0.3], [0.1, -0.2]], dtype=torch.float64)
    target = apply_probe(w, z)
    fitted, mse = fit_probe(z.float(), target)
    torch.testing.assert_close(fitted, w, rtol=0, atol=1e-5)
    assert float(mse) < 1e-10


# --------------------------------------------------------------------------- CLI


def _args(tmp_path: Path) -> list[str]:
    return [
        f"--trainer.default_root_dir={tmp_path}",
        f"--trainer.logger.init_args.save_dir={tmp_path}",
        "--trainer.enable_progress_bar=false",
        f"--data.init_args.cache_dir={tmp_path / 'cache'}",
        "--data.init_args.n_trajectories=6",
        "--data.init_args.n_frames=8",
        "--data.init_args.rollout_frames=12",
        "--data.init_args.test_fraction=0.34",
        "--data.init_args.batch_size=10",
    ]


@pytest.fixture(scope="module", params=["pixel.yaml", "pixel_baseline.yaml"])
def fitted(request, tmp_path_factory):
    """A 4-step fit (2 epochs of 2 batches) of a bundled pixel config on tiny data."""
    tmp_path = tmp_path_factory.mktemp(request.param.split(".")[0])
    args = ["fit", "--config", request.param, "--trainer.max_steps=4"]
    args += ["--trainer.log_every_n_steps=1", "--trainer.check_val_every_n_epoch=1"]
    args += ["--trainer.callbacks.init_args.every_n_epochs=1", *_args(tmp_path)]
    return request.param, tmp_path, cli_main(args)


def test_short_fit_logs_losses_rollout_metrics_and_images(fitted):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config, _, cli = fitted
    assert cli.trainer.global_step == 4
    assert type(cli.model) is (AutoencoderBaseline if "baseline" in config else AutoencoderHNN)
    assert cli.model.hparams.input_dim == 1568  # linked from data.state_dim
    log_dir = cli.trainer.logger.log_dir
    ckpts = sorted(p.name for p in Path(log_dir, "checkpoints").glob("*.ckpt"))
    assert ckpts == ["epoch=1-step=4.ckpt", "last.ckpt"]
    acc = EventAccumulator(log_dir, size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    scalars, images = set(acc.Tags()["scalars"]), set(acc.Tags()["images"])
    expected = {f"{s}/{p}" for s in ("train", "val") for p in ("loss", "recon", "canonical")}
    expected |= {"train/latent", "val/latent"}
    expected |= {f"rollout/{m}" for m in ("energy_mse", "state_mse", "pixel_mse", "latent_mse")}
    assert expected <= scalars
    assert ("rollout/conserved_drift" in scalars) == ("baseline" not in config)
    assert {"rollout/frames", "rollout/phase_portrait", "rollout/energy"} <= images
    # rollouts ran at both epoch ends (steps 2 and 4)
    assert [e.step for e in acc.Scalars("rollout/energy_mse")] == [2, 4]
    frames = acc.Images("rollout/frames")[-1]
    assert frames.height > 2 * 28 * 4 + 2 and frames.width > 10 * 28 * 4 + 9  # + labels


def test_callback_run_returns_consistent_metrics_and_rollout(fitted):
    config, _, cli = fitted
    protocol = evaluation.task_protocol("pixel", "clean").replace(n_points=15, method="rk4")
    cli.model.train()
    metrics, r = evaluation.evaluate(cli.model, cli.datamodule, protocol)
    assert cli.model.training  # evaluated in eval mode, training mode restored
    assert (
        isinstance(r, Rollout)
        and r.has_frames
        and all(isinstance(v, float) for v in metrics.values())
    )
    assert r.z_pred.shape == (15, 2, 2) and r.x_pred.shape == r.x_true.shape == (15, 2, 1568)
    assert r.y_true.shape == r.y_pred.shape == (15, 2, 2)
    dm = cli.datamodule
    e = 1.875 * (1 - torch.cos(r.y_pred[..., 0])) + r.y_pred[..., 1] ** 2
    torch.testing.assert_close(r.e_pred, e)
    e_mse = float(((dm.energy(dm.rollout_truth(n_points=15)[1]).double() - e) ** 2).mean())
    assert metrics["energy_mse"] == pytest.approx(e_mse, rel=1e-5)
    pix = float(((r.x_pred - r.x_true) ** 2).mean())
    assert metrics["pixel_mse"] == pytest.approx(pix, rel=1e-6)
    # the rollout starts at the encoding of the first true pair
    torch.testing.assert_close(r.z_pred[0], r.z_true[0], rtol=0, atol=1e-6)
    if "baseline" in config:
        assert r.h_pred is None and "conserved_drift" not in metrics
    else:
        assert r.h_pred.shape == (15, 2) and metrics["conserved_drift"] >= 0
    img = plotting.frames_image(r)
    assert img.dtype == torch.uint8 and img.shape == (1, 2 * 28 * 4 + 2, 10 * 28 * 4 + 9)
    strip = plotting.frames_figure(r).axes[0]
    assert [t.get_text() for t in strip.get_yticklabels()] == ["true", "predicted"]
    times = [float(t.get_text()) for t in strip.get_xticklabels()]
    assert times[0] == 0 and times[-1] == pytest.approx(float(r.t[-1]), abs=0.01)
    energy = plotting.energy_over_time(r)
    assert any("semi-implicit Euler" in t.get_text() for t in energy.texts)


def test_reference_protocol_reads_decoded_frames_through_the_probe_model(fitted):
    """The reference's evaluation: latent over [0, model_t_end] frames, decoded,
    re-encoded by the probe model's encoder, read by its probe, H with α = 1.9."""
    _, _, cli = fitted
    model, dm = cli.model, cli.datamodule
    n = 15
    protocol = evaluation.task_protocol("pixel", "reference").replace(
        n_points=n, model_t_end=0.98 * n
    )
    own, r = evaluation.evaluate(model, dm, protocol)
    assert r.y_true.shape == (n, 1, 2) and r.x_pred.shape == (n, 1, 1568)
    _, y_true, x_true = dm.trajectory_truth(*protocol.start, n)
    torch.testing.assert_close(r.x_true, x_true)
    t_model = torch.linspace(0, 0.98 * n, n, dtype=torch.float64) * model.frame_dt
    z = evaluation.rollout(model, x_true[0], t_model, rtol=1e-9, atol=1e-9).y_pred
    torch.testing.assert_close(r.z_pred, z, rtol=0, atol=1e-7)
    with torch.no_grad():
        z_read = model.encode(r.x_pred)
    torch.testing.assert_close(r.y_pred, apply_probe(r.probe, z_read))
    e = 1.9 * (1 - torch.cos(r.y_pred[..., 0])) + r.y_pred[..., 1] ** 2
    torch.testing.assert_close(r.e_pred, e)
    same = evaluation.evaluate(model, dm, protocol, probe_model=model)[0]
    assert same == pytest.approx(own, rel=1e-9)
    # another model's encoder: the probe is fitted on its encodings and reads through it
    torch.manual_seed(1)
    other = AutoencoderHNN(input_dim=1568)
    metrics, r2 = evaluation.evaluate(model, dm, protocol, probe_model=other)
    x_train, qp_train = dm.probe_data()
    with torch.no_grad():
        probe, _ = fit_probe(other.encode(x_train), qp_train)
        torch.testing.assert_close(r2.probe, probe)
        torch.testing.assert_close(r2.y_pred, apply_probe(probe, other.encode(r2.x_pred)))
    torch.testing.assert_close(r2.z_pred, r.z_pred)  # the model's own latent rollout
    assert metrics["energy_mse"] != own["energy_mse"]
    # the "own" setting ignores a probe model
    ignored = evaluation.evaluate(
        model, dm, protocol.replace(probe_encoder="own"), probe_model=other
    )[0]
    assert ignored == pytest.approx(own, rel=1e-9)


def test_test_command_under_both_inference_modes(fitted):
    config, tmp_path, cli = fitted
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    for inference_mode in ("false", "true"):
        test = cli_main(
            ["test", "--config", config, "--ckpt_path", ckpt]
            + [f"--trainer.inference_mode={inference_mode}", *_args(tmp_path)]
            + ["--data.init_args.batch_size=3"]  # 10 test rows: batches of 3, 3, 3, 1
        )
        metrics = test.trainer.callback_metrics
        keys = {"test/loss", "test/recon", "rollout/energy_mse", "rollout/pixel_mse"}
        assert keys <= set(metrics)
        assert all(torch.isfinite(v) for v in metrics.values())
    # test/loss (a batch-size-weighted mean) is the loss of the whole test split as one batch
    model, dm = cli.model, cli.datamodule
    with torch.no_grad():
        full = model.losses(dm.x_test, dm.dx_test)["loss"]
    torch.testing.assert_close(metrics["test/loss"], full, rtol=1e-5, atol=0)


def test_checkpoint_round_trip_decodes_the_same_rollout(fitted):
    config, _, cli = fitted
    cls = AutoencoderBaseline if "baseline" in config else AutoencoderHNN
    loaded = cls.load_from_checkpoint(cli.trainer.checkpoint_callback.best_model_path)
    assert len(loaded.hparams) == 22  # 15 model arguments and 7 of the training recipe
    assert all(loaded.hparams[k] == cli.model.hparams[k] for k in loaded.hparams)
    x0 = cli.datamodule.rollout_x[0]
    z_a, x_a = loaded.rollout(x0, 30, method="rk4")
    z_b, x_b = cli.model.rollout(x0, 30, method="rk4")
    assert x_a.shape == (30, 2, 1568) and z_a.dtype == torch.float64
    torch.testing.assert_close(x_a, x_b, rtol=0, atol=0)
    torch.testing.assert_close(z_a, z_b, rtol=0, atol=0)
    assert not torch.allclose(z_a[-1], z_a[0])  # the latent moves
