"""The wheel: built from a copy of the checkout, installed into a fresh venv, run from an
unrelated directory. It must carry the bundled configs and the ``hnn-pl`` script.

No network and no multi-GB install: the wheel is built with the setuptools of this venv
(``--no-build-isolation``) and installed with ``--no-deps``; the fresh venv then sees
this venv's site-packages (torch, Lightning, ...) through a ``.pth`` file, after its own,
so ``import hnn_pl`` finds the installed wheel and not the checkout.
"""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

import hnn_pl
from hnn_pl.commands.config_paths import bundled_configs

REPO = Path(__file__).resolve().parent.parent
#: what the build needs: pyproject.toml names README.md as the long description
SOURCES = ("pyproject.toml", "README.md", "hnn_pl", "configs")


def _run(cmd: list, cwd: Path, env: dict | None = None) -> str:
    proc = subprocess.run(
        [str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def _build_wheel(tmp: Path) -> Path:
    """Build in a copy, so the checkout gets no ``build/`` or ``*.egg-info``."""
    src = tmp / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name, ignore=ignore)
        else:
            shutil.copy2(REPO / name, src / name)
    pip_wheel = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation"]
    _run([*pip_wheel, "--no-index", "-q", "-w", tmp / "dist", src], cwd=tmp)
    (wheel,) = (tmp / "dist").glob("hnn_pl-*.whl")
    return wheel


def _fresh_venv(tmp: Path, wheel: Path) -> Path:
    """A venv holding only the wheel, then pointed at this venv's packages."""
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp)
    python = venv / "bin" / "python"
    # install before the .pth exists, so pip sees no hnn_pl (the checkout's) already there
    _run([sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps",
          "--no-index", wheel], cwd=tmp)  # fmt: skip
    purelib = _run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp)
    ours = [sysconfig.get_path("purelib"), *site.getsitepackages()]
    Path(purelib.strip(), "_hnn_pl_test_deps.pth").write_text("\n".join(dict.fromkeys(ours)))
    return venv


@pytest.mark.slow
def test_wheel_ships_configs_and_runs_from_anywhere(tmp_path):
    had_build = (REPO / "build").exists()
    wheel = _build_wheel(tmp_path)
    assert (REPO / "build").exists() == had_build, "the test left a build/ in the checkout"

    names = set(zipfile.ZipFile(wheel).namelist())
    configs = bundled_configs()
    assert configs and {f"hnn_pl/configs/{c}" for c in configs} <= names
    modules = {p.relative_to(tmp_path / "src").as_posix() for p in (tmp_path / "src").rglob("*")}
    modules = {m for m in modules if m.startswith("hnn_pl/") and m.endswith(".py")}
    assert modules <= names, f"modules missing from the wheel: {sorted(modules - names)}"
    assert {"hnn_pl/data/real_pend_h_1.txt", "hnn_pl/data/real_pendulum.csv"} <= names
    assert f"hnn_pl-{hnn_pl.__version__}.dist-info/entry_points.txt" in names

    venv = _fresh_venv(tmp_path, wheel)
    python, script = venv / "bin" / "python", venv / "bin" / "hnn-pl"
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(HNN_PL_CACHE=str(tmp_path / "cache"), OMP_NUM_THREADS="1", PYTHONNOUSERSITE="1")

    where = _run(
        [
            python,
            "-c",
            "import hnn_pl.commands.config_paths as c; print(c.__file__); print(c.CONFIG_DIR)",
        ],
        run_dir,
        env,
    ).split()
    assert all(Path(w).is_relative_to(venv) for w in where), where

    out = _run([python, "-m", "hnn_pl", "--help"], run_dir, env)
    assert "usage: python -m hnn_pl" in out and all(c in out for c in configs), out
    out = _run([script, "--help"], run_dir, env)
    assert out.startswith("usage: hnn-pl <command>") and all(c in out for c in configs), out
    assert _run([script, "--version"], run_dir, env).split() == ["hnn_pl", hnn_pl.__version__]
    out = _run([script, "fit", "--model.help", "HNN"], run_dir, env)
    assert out.startswith("usage: hnn-pl") and "--model.hidden_dim" in out, out

    fit = [python, "-m", "hnn_pl", "fit", "--config", "real_pendulum.yaml"]
    _run(
        [*fit, "--trainer.max_steps", "20", "--trainer.enable_progress_bar", "false"], run_dir, env
    )
    assert list((run_dir / "lightning_logs").rglob("*.ckpt")), "no checkpoint under the run dir"


def test_pyproject_lists_every_package_and_maps_the_configs():
    """The packages are listed by hand (for the mapping): a new one must be added."""
    tomllib = pytest.importorskip("tomllib")
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {
        ".".join(p.parent.relative_to(REPO).parts)
        for p in (REPO / "hnn_pl").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert set(setuptools["packages"]) == on_disk | {"hnn_pl.configs"}
    assert setuptools["package-dir"] == {"hnn_pl.configs": "configs"}
