"""Faults and bad input (STABILITY.md, "Faults and bad input"): every failure of a CLI
command is one line on stderr and exit status 2, before anything is written; a
checkpoint is data; non-finite states get a status; writes are whole."""

from __future__ import annotations

import errno
import math
import os
import queue
import random
import re
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import fault_cases_commands
import fault_cases_recording
import fault_cases_resume
import pytest
import torch
from forks import Forks

from hnn_pl.integrate import METHODS, Status, odeint

ROOT = Path(__file__).resolve().parent.parent
F64 = torch.float64

# ---------------------------------------------------------------- files the cases use

EVIL = 'open("MARKER", "w").write("ran")\n\nclass Evil:\n    pass\n'

SYSTEMS = """
import torch
from hnn_pl.systems.base import HamiltonianSystem


class Spring(HamiltonianSystem):
    def hamiltonian(self, y):
        return 0.5 * y.square().sum(-1)

    def sample_initial(self, n, generator):
        return torch.rand(n, 2, generator=generator, dtype=torch.float64) + 0.1


class WideH(Spring):
    def hamiltonian(self, y):
        return 0.5 * y.square()


class HalfNaN(Spring):
    def hamiltonian(self, y):
        h = 0.5 * y.square().sum(-1)
        return torch.where(y[..., 0] > 0.6, torch.nan, h)


class WideSampler(Spring):
    def sample_initial(self, n, generator):
        return torch.rand(n, 3, generator=generator, dtype=torch.float64)


class Float32Sampler(Spring):
    def sample_initial(self, n, generator):
        return torch.rand(n, 2, generator=generator)
"""


def _checkpoint(names: dict) -> dict:
    """A checkpoint of a fresh HNN (2-D states) whose saved class names are ``names``."""
    from hnn_pl.models import HNN

    hparams = {"_class_path": "hnn_pl.models.HNN", "input_dim": 2, "hidden_dim": 200}
    ckpt = {"state_dict": HNN().state_dict(), "hyper_parameters": hparams}
    ckpt["hnn_pl_model_class"] = "hnn_pl.models.hnn.HNN"
    for key, value in names.items():
        (hparams if key == "_class_path" else ckpt)[key] = value
    return ckpt


def _files(kind: str, tmp: Path) -> None:
    """Make the file a case needs in its working directory ``tmp``."""
    if kind in fault_cases_recording.FILES:
        return fault_cases_recording.FILES[kind](tmp)
    if kind in fault_cases_resume.FILES:
        return fault_cases_resume.FILES[kind](tmp)
    if kind in fault_cases_commands.FILES:
        return fault_cases_commands.FILES[kind](tmp)
    if kind == "empty-config":
        (tmp / "empty.yaml").write_text("")
    elif kind == "base-missing":
        (tmp / "mine.yaml").write_text("base: sprng.yaml\ntrainer: {max_steps: 2}\n")
    elif kind == "base-cycle":
        (tmp / "a.yaml").write_text("base: b.yaml\ntrainer: {max_steps: 2}\n")
        (tmp / "b.yaml").write_text("base: a.yaml\n")
    elif kind in ("zero", "truncated", "random", "hostile-class-path", "hostile-model-class"):
        (tmp / "evilmod.py").write_text(EVIL)
        ckpt = tmp / "model.ckpt"
        if kind == "zero":
            ckpt.write_bytes(b"")
        elif kind == "random":
            ckpt.write_bytes(b"\x80\x19" + random.Random(0).randbytes(4094))
        elif kind == "truncated":
            torch.save(_checkpoint({}), ckpt)
            ckpt.write_bytes(ckpt.read_bytes()[:5000])
        else:
            key = "_class_path" if kind == "hostile-class-path" else "hnn_pl_model_class"
            torch.save(_checkpoint({key: "evilmod.Evil"}), ckpt)
    elif kind == "ckpt-dir":
        (tmp / "model.ckpt").mkdir()
    elif kind.startswith("starts-"):
        torch.save(_checkpoint({}), tmp / "model.ckpt")
        starts = {
            "starts-list": [1.0, 2.0],
            "starts-width": torch.ones(3, 4),
            "starts-inf": torch.tensor([[0.5, 0.0], [math.inf, 0.0]]),
        }.get(kind)
        if starts is not None:
            torch.save(starts, tmp / "starts.pt")
    elif kind == "systems":
        (tmp / "mysys.py").write_text(SYSTEMS)
    elif kind == "out-dir":
        (tmp / "results").mkdir()


FIT = ["fit", "--config", "spring_fast.yaml", "--trainer.max_steps=2"]
TEST = ["test", "--config", "spring_fast.yaml", "--ckpt_path", "model.ckpt"]
PREDICT = [
    "predict",
    "--config",
    "spring_fast.yaml",
    "--ckpt_path",
    "model.ckpt",
    "--trainer.callbacks+=hnn_pl.callbacks.RolloutWriter",
    "--trainer.callbacks.starts=starts.pt",
]

#: id: (argv, files, what the line must say)
CASES = {
    "threads-abc": ([*FIT, "--threads", "abc"], "", "threads must be >= 1 or 'auto', got 'abc'"),
    "max-steps-negative": (
        ["fit", "--config", "spring_fast.yaml", "--trainer.max_steps=-5"],
        "",
        "`max_steps` must be a non-negative integer or -1",
    ),
    "empty-config": (
        ["fit", "--config", "empty.yaml"],
        "empty-config",
        "empty.yaml: the file is empty",
    ),
    "config-base-missing": (
        ["fit", "--config", "mine.yaml"],
        "base-missing",
        "mine.yaml: base 'sprng.yaml' is neither a file beside it nor a bundled config; "
        "did you mean spring.yaml?",
    ),
    "config-base-cycle": (
        ["validate", "--config", "a.yaml"],
        "base-cycle",
        "a.yaml: its bases form a cycle: a.yaml -> b.yaml -> a.yaml",
    ),
    "class-path-typo": (
        [*FIT, "--model", "hnn_pl.models.HNNN"],
        "",
        "no class HNNN in hnn_pl.models; did you mean hnn_pl.models.HNN?",
    ),
    "short-class-typo": (
        [*FIT, "--data.init_args.system", "MassSprin"],
        "",
        "unknown class 'MassSprin'; did you mean MassSpring?",
    ),
    "option-typo": (
        [*FIT, "--model.init_args.hidden_dimm", "3"],
        "",
        "has no option 'hidden_dimm'; did you mean hidden_dim?",
    ),
    "trainer-option-typo": (
        [*FIT, "--trainer.max_stepz", "3"],
        "",
        "unknown option --trainer.max_stepz; did you mean --trainer.max_steps",
    ),
    "config-name-typo": (
        ["fit", "--config", "sprng_fast"],
        "",
        "did you mean spring_fast.yaml?",
    ),
    "data-beyond-memory": (
        [*FIT, "--data.init_args.n_trajectories=1000000000"],
        "",
        "trajectories × 30 points needs about",
    ),
    "missing-checkpoint": (TEST, "", "checkpoint model.ckpt: no such file"),
    "missing-resume-checkpoint": (
        [*FIT, "--ckpt_path", "model.ckpt"],
        "",
        "checkpoint model.ckpt: no such file",
    ),
    "zero-byte-checkpoint": (TEST, "zero", "checkpoint model.ckpt: the file is empty"),
    "truncated-checkpoint": (TEST, "truncated", "model.ckpt: cannot be read (truncated"),
    "random-bytes-checkpoint": (TEST, "random", "model.ckpt: cannot be read"),
    "checkpoint-is-a-directory": (
        TEST,
        "ckpt-dir",
        "model.ckpt: a directory without checkpoints/last.ckpt",
    ),
    "hostile-class-path": (TEST, "hostile-class-path", "holds a evilmod.Evil but the config"),
    "hostile-model-class": (TEST, "hostile-model-class", "holds a evilmod.Evil but the config"),
    "starts-missing": (PREDICT, "starts-none", "starts starts.pt: no such file"),
    "starts-not-a-tensor": (PREDICT, "starts-list", "holds a list; expected a float tensor"),
    "starts-wrong-width": (PREDICT, "starts-width", "shape (3, 4); the model's states need (B, 2)"),
    "starts-not-finite": (PREDICT, "starts-inf", "1 of 2 rows are not finite"),
    "system-h-shape": (
        [*FIT, "--data.init_args.system=mysys.WideH"],
        "systems",
        "system mysys.WideH: hamiltonian returned (50, 2) for states of shape (50, 2)",
    ),
    "system-h-nan": (
        [*FIT, "--data.init_args.system=mysys.HalfNaN"],
        "systems",
        "system mysys.HalfNaN: hamiltonian is not finite at",
    ),
    "system-sampler-width": (
        [*FIT, "--data.init_args.system=mysys.WideSampler"],
        "systems",
        "system mysys.WideSampler: sample_initial returned shape (50, 3); expected (50, 2)",
    ),
    "system-sampler-dtype": (
        [*FIT, "--data.init_args.system=mysys.Float32Sampler"],
        "systems",
        "system mysys.Float32Sampler: sample_initial returned torch.float32",
    ),
    "reproduce-out-is-a-directory": (
        ["reproduce", "--out", "results"],
        "out-dir",
        "--out results is a directory",
    ),
}
CASES |= fault_cases_recording.CASES
CASES |= fault_cases_resume.CASES
CASES |= fault_cases_commands.CASES


def _run_case(case: str, tmp: Path, forks: queue.Queue) -> tuple[int, str, set[Path]]:
    """``python -m hnn_pl`` for ``case`` in ``tmp`` (through a free :class:`~forks.Forks`):
    exit status, stderr, and the files it left that were not there before."""
    argv, files, _ = CASES[case]
    (tmp / "cwd").mkdir()
    _files(files, tmp / "cwd")
    before = set((tmp / "cwd").rglob("*"))
    env = {"PYTHONPATH": str(ROOT), "HNN_PL_CACHE": str(tmp / "cwd" / "cache")}
    server = forks.get()
    try:
        code, stderr = server.run(argv, tmp / "cwd", env, ["HNN_PL_TRACEBACK"], tmp)
    finally:
        forks.put(server)
    return code, stderr, set((tmp / "cwd").rglob("*")) - before


@pytest.fixture(scope="module")
def cli_servers():
    """A fork server of ``python -m hnn_pl`` (:class:`~forks.Forks`) in a queue: a test
    takes it, runs a command in a forked child (no imports), and puts it back. One: the
    suite's other worker keeps the second core busy, and a second server's imports and
    warm-up cost CPU for nothing (this file's default tier: 91 s of CPU with two, 67 s
    with one)."""
    forks: queue.Queue = queue.Queue()
    servers = [Forks()]
    for server in servers:
        forks.put(server)
    yield forks
    for server in servers:
        server.close()


@pytest.fixture(scope="module")
def cli_runs(request, tmp_path_factory, cli_servers):
    """The selected cases, each in a forked child of the fork server (a second thread
    prepares the next case's files meanwhile)."""
    selected = [
        item.callspec.params["case"]
        for item in request.session.items
        if item.originalname == "test_every_cli_failure_is_one_line_and_leaves_nothing"
    ]
    forks = cli_servers

    def forked(argv: list[str], cwd: Path, env: dict) -> None:
        server = forks.get()
        try:
            code, stderr = server.run(argv, cwd, env, [], cwd)
        finally:
            forks.put(server)
        assert code == 0, stderr

    fault_cases_resume.RUN = forked
    pool = ThreadPoolExecutor(2)
    runs = {c: pool.submit(_run_case, c, tmp_path_factory.mktemp(c), forks) for c in selected}
    yield runs
    pool.shutdown(cancel_futures=True)
    fault_cases_resume.RUN = fault_cases_resume._subprocess


@pytest.mark.parametrize("case", list(CASES))
def test_every_cli_failure_is_one_line_and_leaves_nothing(case, cli_runs):
    code, stderr, new = cli_runs[case].result()
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert "Traceback" not in stderr, stderr
    assert code == 2 and len(lines) == 1, stderr  # no "Seed set", device banner, warning
    assert lines[0].startswith("python -m hnn_pl: error: ")
    assert CASES[case][2] in lines[0]
    assert "weights_only" not in stderr
    leftovers = sorted(str(p) for p in new if "__pycache__" not in p.parts)
    assert leftovers == [], f"written: {leftovers}"  # MARKER too: evilmod was never imported


# ----------------------------------------------------------------- unit-level cases


def test_checkpoint_hyperparameters_restore_only_plain_options():
    from types import SimpleNamespace

    from hnn_pl.safe_io import checkpoint_init_args

    ckpt = {
        "hyper_parameters": {
            "hidden_dim": {"class_path": "evilmod.Evil"},
            "n_hidden": 3,
            "input_dim": 8,
            "unknown": 1,
            "activation": "softplus",
        }
    }
    current = SimpleNamespace(hidden_dim=200, n_hidden=2, input_dim=2, activation="tanh")
    assert checkpoint_init_args(ckpt, current) == {"n_hidden": 3, "activation": "softplus"}


def _started_run(save_dir: Path):
    """A trainer with the project's logger, its :class:`RefusedRun` taken before the run
    starts, and the run directory as Lightning leaves it at setup (an event file and
    LightningCLI's ``config.yaml``)."""
    from lightning.pytorch import Trainer

    from hnn_pl.commands.cli import RefusedRun
    from hnn_pl.loggers import TensorBoardLogger

    logger = TensorBoardLogger(save_dir=str(save_dir), name="spring_hnn")
    trainer = Trainer(logger=logger, accelerator="cpu", enable_progress_bar=False)
    run = RefusedRun(trainer, "config.yaml")
    logger.experiment.flush()
    (Path(logger.log_dir) / "config.yaml").write_text("seed_everything: 0\n")
    return logger, run


def test_a_refused_run_takes_back_only_what_it_wrote(tmp_path):
    logger, run = _started_run(tmp_path / "logs")
    run.discard()
    assert not (tmp_path / "logs").exists()

    (tmp_path / "logs" / "spring_hnn" / "version_0").mkdir(parents=True)
    (tmp_path / "logs" / "spring_hnn" / "notes.txt").write_text("mine\n")
    logger, run = _started_run(tmp_path / "logs")
    assert Path(logger.log_dir).name == "version_1"
    run.discard()
    kept = sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "logs").rglob("*"))
    assert kept == ["logs/spring_hnn", "logs/spring_hnn/notes.txt", "logs/spring_hnn/version_0"]

    logger, run = _started_run(tmp_path / "ckpt")
    checkpoint = Path(logger.log_dir) / "checkpoints" / "last.ckpt"
    checkpoint.parent.mkdir()
    checkpoint.write_bytes(b"weights")
    run.discard()
    assert checkpoint.is_file() and (checkpoint.parent.parent / "config.yaml").is_file()

    logger, run = _started_run(tmp_path / "metrics")
    logger.log_metrics({"train/loss": 1.0}, step=0)
    run.discard()
    assert (Path(logger.log_dir) / "config.yaml").is_file()


def test_no_module_is_imported_by_a_name_read_from_a_file():
    """Only the package's lazy attribute table imports by name (fixed names)."""
    found = []
    for path in sorted((ROOT / "hnn_pl").rglob("*.py")):
        for line in path.read_text().splitlines():
            if re.search(r"import_module|__import__", line):
                found.append((path.relative_to(ROOT).as_posix(), line.strip()))
    allowed = {
        ("hnn_pl/__init__.py", "value = getattr(importlib.import_module(_LAZY[name]), name)"),
        (
            "hnn_pl/__init__.py",
            'return importlib.import_module(f"{__name__}.{name}")  # name is one of _SUBMODULES',
        ),
    }
    assert set(found) <= allowed, found


@pytest.mark.parametrize("method", list(METHODS))
def test_a_non_finite_start_is_not_ok(method):
    """A tanh field is finite at ``inf``: the row must still stop, at ``t[0]``."""

    def field(t, y):
        return torch.tanh(y.flip(-1)) * torch.tensor([1.0, -1.0], dtype=y.dtype)

    y0 = torch.tensor([[0.5, 0.0], [math.inf, 0.0], [0.0, math.nan]], dtype=F64)
    t = torch.linspace(0, 1, 5, dtype=F64)
    kwargs = {} if method == "dopri5" else {"step_size": 0.1}
    sol = odeint(field, y0, t, method, return_status=True, **kwargs)
    assert sol.status.tolist() == [Status.OK, Status.DIVERGED, Status.DIVERGED]
    assert sol.t_stop[1:].tolist() == [0.0, 0.0] and torch.isnan(sol.y[1:, 1:]).all()
    alone = odeint(field, y0[:1], t, method, **kwargs)
    torch.testing.assert_close(sol.y[:, :1], alone, rtol=0, atol=1e-15)
    with pytest.raises(RuntimeError, match="2 of 3 rows stopped"):
        odeint(field, y0, t, method, **kwargs)


@pytest.mark.parametrize("method", list(METHODS))
def test_a_row_that_overflows_is_not_ok(method):
    """``y' = 10 y`` from 1e307 overflows to inf in the first steps, below any
    blow-up limit that ``1e300 · (1 + |y0|)`` would give (itself inf)."""
    y0 = torch.tensor([[0.5, 0.0], [1e307, 1e307]], dtype=F64)
    t = torch.linspace(0, 1, 5, dtype=F64)
    kwargs = {} if method == "dopri5" else {"step_size": 0.1}
    if method == "leapfrog":
        kwargs["options"] = {"check_separable": False}  # y' = 10 y couples q and p
    sol = odeint(lambda t, y: 10 * y, y0, t, method, return_status=True, blowup=1e300, **kwargs)
    assert sol.status.tolist() == [Status.OK, Status.DIVERGED]


def test_rollout_of_a_model_from_an_infinite_start_is_not_ok():
    from hnn_pl import rollout
    from hnn_pl.models import HNN

    y0 = torch.tensor([[0.5, 0.0], [math.inf, 0.0]])
    out = rollout(HNN(hidden_dim=8), y0, torch.linspace(0, 1, 5), method="rk4")
    assert out.status.tolist() == [Status.OK, Status.DIVERGED]


def test_a_data_set_beyond_the_machine_s_memory_is_refused_before_sampling():
    from hnn_pl.data import SimulatedData
    from hnn_pl.systems import MassSpring

    with pytest.raises(ValueError, match=r"needs about .* of memory; this machine has"):
        SimulatedData(MassSpring(), n_trajectories=10**9)


def test_the_cache_key_covers_a_user_system_s_source(tmp_path, monkeypatch):
    from hnn_pl.data import SimulatedData
    from hnn_pl.systems import MassSpring

    (tmp_path / "mysys_edit.py").write_text(SYSTEMS)
    monkeypatch.syspath_prepend(str(tmp_path))
    import mysys_edit

    before = SimulatedData(mysys_edit.Spring(), cache_dir=str(tmp_path)).cache_path
    edited = SYSTEMS.replace("0.5 * y.square().sum(-1)", "0.7 * y.square().sum(-1)", 1)
    (tmp_path / "mysys_edit.py").write_text(edited)
    after = SimulatedData(mysys_edit.Spring(), cache_dir=str(tmp_path)).cache_path
    assert before != after
    assert "source" not in SimulatedData(MassSpring()).cache_params()


# --------------------------------------------------------------------- disk full


class _FullDisk:
    """``open`` for :mod:`hnn_pl.safe_io` whose files take ``room`` bytes, then raise
    ``ENOSPC`` (what a write to a full file system does)."""

    def __init__(self, room: int) -> None:
        self.room = room

    def __call__(self, path, mode="r", *args, **kwargs):
        f = open(path, mode, *args, **kwargs)  # noqa: SIM115
        room, write = self.room, f.write

        def limited(data):
            nonlocal room
            data = bytes(data)
            if len(data) > room:
                write(data[:room])
                raise OSError(errno.ENOSPC, "No space left on device")
            room -= len(data)
            return write(data)

        f.write = limited
        return f


@pytest.mark.parametrize("seed", range(40))
def test_random_bytes_are_refused_in_one_line_without_warnings(seed, tmp_path):
    """A checkpoint, a starts file or a recording of random bytes. Half the files open
    with a pickle PROTO opcode and a random protocol number, on which torch warns before
    failing; the warning is noise once the file is refused."""
    import warnings

    from hnn_pl import safe_io

    rng = random.Random(seed)
    data = rng.randbytes(rng.choice([16, 256, 4096]))
    if seed % 2 == 0:
        data = b"\x80" + bytes([rng.randrange(3, 256)]) + data[2:]
    path = tmp_path / "file.pt"
    path.write_bytes(data)
    from hnn_pl.data.recording import load_recording
    from hnn_pl.evaluation.observer import read_positions_window

    loaders = {
        "checkpoint": (safe_io.load_checkpoint, f"checkpoint {path}: cannot be read"),
        "starts": (lambda p: read_positions_window(p, 2), f"starts {path}: cannot be read"),
        "recording": (load_recording, "not a torch.save file of tensors"),
    }
    for load, message in loaders.values():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(ValueError, match=re.escape(message)):
                load(path)
        assert [str(w.message) for w in caught] == []


def test_a_full_disk_never_replaces_a_good_checkpoint(tmp_path, monkeypatch):
    from hnn_pl import safe_io

    path = tmp_path / "checkpoints" / "last.ckpt"
    io = safe_io.atomic_checkpoint_io()
    io.save_checkpoint({"state_dict": {"w": torch.ones(3)}}, path)
    monkeypatch.setattr(safe_io, "open", _FullDisk(100), raising=False)
    with pytest.raises(OSError, match=f"^no space left on {re.escape(str(path.parent))}$"):
        io.save_checkpoint({"state_dict": {"w": torch.zeros(10_000)}}, path)
    assert sorted(p.name for p in path.parent.iterdir()) == ["last.ckpt"]
    assert torch.equal(safe_io.load_checkpoint(path)["state_dict"]["w"], torch.ones(3))


def test_a_full_disk_leaves_no_partial_cache(tmp_path, monkeypatch):
    from hnn_pl import safe_io
    from hnn_pl.data import SimulatedData
    from hnn_pl.systems import MassSpring

    dm = SimulatedData(MassSpring(), cache_dir=str(tmp_path / "cache"))
    monkeypatch.setattr(safe_io, "open", _FullDisk(1000), raising=False)
    with pytest.raises(OSError, match=f"no space left on {re.escape(str(tmp_path / 'cache'))}"):
        dm.prepare_data()
    assert list((tmp_path / "cache").iterdir()) == []


def _small_filesystem(path: Path, size: str) -> bool:
    path.mkdir()
    if os.geteuid() != 0 or not sys.platform.startswith("linux"):
        return False
    mount = ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)]
    return subprocess.run(mount, capture_output=True).returncode == 0


def test_fit_on_a_full_file_system_says_so_in_one_line(tmp_path, cli_servers):
    """A real full file system where the machine allows a small tmpfs (root on Linux):
    the cache does not fit; one line names the directory; nothing partial is left."""
    full = tmp_path / "full"
    if not _small_filesystem(full, "64k"):
        pytest.skip("cannot mount a small file system here (the ENOSPC tests above hold)")
    try:
        env = {"PYTHONPATH": str(ROOT), "HNN_PL_CACHE": str(full / "cache")}
        argv = [*FIT, "--data.init_args.n_trajectories=400", "--trainer.logger=false"]
        (tmp_path / "out").mkdir()
        server = cli_servers.get()
        try:
            code, stderr = server.run(argv, tmp_path, env, ["HNN_PL_TRACEBACK"], tmp_path / "out")
        finally:
            cli_servers.put(server)
        lines = [line for line in stderr.splitlines() if line.strip()]
        assert code == 2 and "Traceback" not in stderr, stderr
        assert lines[-1] == f"python -m hnn_pl: error: no space left on {full / 'cache'}"
        assert list((full / "cache").iterdir()) == []
    finally:
        subprocess.run(["umount", str(full)], capture_output=True)


# ------------------------------------------------------------------- reproduce


def _reproduce(tmp: Path) -> subprocess.Popen:
    """A ``reproduce`` of two long runs on one worker, started; returns once it says its
    runs have started."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HNN_PL_CACHE": str(tmp / "cache")}
    env["TMPDIR"] = str(tmp)  # a killed reproduce cannot remove its models' folder
    argv = ["--tasks", "real_pendulum", "--models", "hnn", "--seeds", "2", "--workers", "1"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "hnn_pl", "reproduce", *argv, "--max-steps", "1000000"],
        cwd=tmp,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    for line in proc.stdout:
        if "runs on 1 worker" in line:
            return proc
    raise AssertionError(proc.stderr.read())


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _worker(pid: int) -> int | None:
    """The pool worker among ``pid``'s children (not the resource tracker)."""
    for child in _children(pid):
        try:
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                return child
        except OSError:
            continue
    return None


def _wait_for(condition, seconds: float = 120.0) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.2)
    return False


linux_only = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")


def _kill_leaves_no_child(proc: subprocess.Popen) -> None:
    """Once ``proc`` runs its pool worker and the resource tracker, SIGKILL it (no handler
    runs); both children must exit by themselves."""
    assert _wait_for(lambda: _worker(proc.pid) is not None and len(_children(proc.pid)) >= 2)
    children = _children(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert _wait_for(lambda: not any(Path(f"/proc/{c}").exists() for c in children), 30)


@pytest.mark.slow
@linux_only
def test_killing_reproduce_leaves_no_worker_or_resource_tracker(tmp_path):
    """``reproduce`` itself, its worker training: :func:`test_killing_the_pool_s_parent_
    leaves_no_worker_or_resource_tracker` is the same pool with runs that wait."""
    _kill_leaves_no_child(_reproduce(tmp_path))


@pytest.mark.slow
@linux_only
def test_ctrl_c_and_a_dead_worker_end_in_one_line(tmp_path):
    proc = _reproduce(tmp_path)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert err.strip().splitlines()[-1] == (
        "python -m hnn_pl reproduce: interrupted: 0 of 2 runs finished, nothing written"
    )
    proc = _reproduce(tmp_path)
    assert _wait_for(lambda: _worker(proc.pid) is not None)
    os.kill(_worker(proc.pid), signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2 and "Traceback" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.endswith(
        "a worker process died (killed, or out of memory): 0 of 2 runs finished, nothing written"
    ), err
    assert not (tmp_path / "results").exists()


#: a ``reproduce`` whose runs wait (their build sleeps): the pool's start and stop alone
_WAITING_RUNS = """
import sys, time
from concurrent.futures.process import BrokenProcessPool
from hnn_pl.experiments import collect

def build(config, options=(), save_config=False):
    time.sleep(120)

if __name__ == "__main__":
    print("started", flush=True)
    try:
        collect.run_jobs([("spring", "hnn", 0), ("spring", "hnn", 1)], 1, print, {}, build=build)
    except (KeyboardInterrupt, BrokenProcessPool) as err:
        print(type(err).__name__, file=sys.stderr)
        sys.exit(3)
"""


def _waiting_runs(tmp: Path) -> subprocess.Popen:
    """:data:`_WAITING_RUNS` started in its own session; returns once it says so."""
    script = tmp / "runs.py"
    script.write_text(_WAITING_RUNS)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, str(script)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.stdout.readline() == "started\n"
    return proc


@linux_only
def test_killing_the_pool_s_parent_leaves_no_worker_or_resource_tracker(tmp_path):
    """SIGKILL to the process that runs the pool (no handler runs): its worker and the
    resource tracker exit by themselves."""
    _kill_leaves_no_child(_waiting_runs(tmp_path))


@linux_only
@pytest.mark.parametrize("delay", [0.0, 0.3, 1.5])
@pytest.mark.parametrize("stop", ["ctrl-c", "dead worker"])
def test_the_pool_stops_in_one_line_at_any_moment_of_its_life(tmp_path, delay, stop):
    """Ctrl-C to the process group, or a worker killed, while the pool starts its worker,
    while the worker imports, while it runs: ``run_jobs`` kills the pool, waits for its
    manager thread and raises; nothing else is printed (no ``Bad file descriptor`` from
    the interpreter's exit hook, no worker traceback) and the process exits."""
    proc = _waiting_runs(tmp_path)
    time.sleep(delay)
    if stop == "dead worker":
        assert _wait_for(lambda: _worker(proc.pid) is not None, 60)
        os.kill(_worker(proc.pid), signal.SIGKILL)
    else:
        os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    expected = "KeyboardInterrupt" if stop == "ctrl-c" else "BrokenProcessPool"
    assert (proc.returncode, err) == (3, expected + "\n"), err


@linux_only
def test_ctrl_c_while_the_pool_starts_is_raised_once_it_has_started():
    """``reproduce`` under load gets Ctrl-C while it spawns its workers: the interrupt
    waits for the start to finish (none inside multiprocessing's launch), and a process
    spawned meanwhile starts with SIGINT blocked (no traceback from a worker that has
    not yet reached the initializer that ignores it)."""
    import threading

    from hnn_pl.experiments.collect import _ctrl_c_held

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers live in the main thread")
    blocked = "import signal; print(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))"
    handler, seen = signal.getsignal(signal.SIGINT), []
    with pytest.raises(KeyboardInterrupt):
        with _ctrl_c_held():
            os.kill(os.getpid(), signal.SIGINT)
            child = subprocess.run([sys.executable, "-c", blocked], capture_output=True, text=True)
            seen.append(child.stdout.strip())
    assert seen == ["True"]
    assert signal.getsignal(signal.SIGINT) is handler
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])


def test_stability_md_lists_every_fault_with_a_test_that_exists():
    from hnn_pl.experiments.stress import FAULTS, faults_section

    assert faults_section() in (ROOT / "STABILITY.md").read_text()
    sources = {p.name: p.read_text() for p in (ROOT / "tests").glob("test_*.py")}
    for _, _, held in FAULTS:
        for name in re.findall(r"test_\w+", held):
            if name.endswith("_py") or name in ("test_faults", "test_bad_input"):
                continue
            assert any(f"def {name}(" in text for text in sources.values()), name
        for case in re.findall(r"\[([\w-]+)\]", held):
            assert case in CASES, case
