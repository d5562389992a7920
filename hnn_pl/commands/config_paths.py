"""Finding configs: a path, or a bare name looked up in the bundled configs.

The bundled configs are the repository's top-level ``configs/``, which the wheel ships
as the package ``hnn_pl.configs`` (``package-dir`` in pyproject.toml), so the same
lookup works in a checkout (editable install) and in an installed wheel.

Kept free of heavy imports so ``python -m hnn_pl --help`` is instant.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def config_dir() -> Path:
    """The directory of the bundled configs (a real directory: wheels install unzipped)."""
    try:
        return Path(str(files("hnn_pl.configs")))
    except ModuleNotFoundError:  # a source tree put on sys.path by hand, not installed
        return Path(__file__).resolve().parents[2] / "configs"


#: the bundled configs
CONFIG_DIR = config_dir()


def resolve_config(name: str) -> str:
    """A config path as given if it exists, else ``<bundled configs>/<name>[.yaml]``.

    Raises:
        FileNotFoundError: neither exists; the message lists the bundled configs.
        ValueError: the file is not a YAML mapping (see :func:`check_config_file`).
    """
    if Path(name).is_file():
        return check_config_file(name)
    for candidate in (CONFIG_DIR / name, CONFIG_DIR / f"{name}.yaml"):
        if candidate.is_file():
            return str(candidate)
    import difflib

    names = bundled_configs()
    stems = {Path(n).stem: n for n in names}
    close = difflib.get_close_matches(Path(name).name, [*names, *stems], n=1, cutoff=0.6)
    if close:
        raise FileNotFoundError(
            f"config {name!r} is neither a file nor a bundled config; did you mean "
            f"{stems.get(close[0], close[0])}?"
        )
    raise FileNotFoundError(
        f"config {name!r} is neither a file nor one of the bundled configs: " + ", ".join(names)
    )


def check_config_file(path: str) -> str:
    """``path`` if it holds a YAML mapping; else ValueError naming the file and the fault."""
    import yaml

    try:
        text = Path(path).read_text(encoding="utf-8")
        data = yaml.safe_load(text)
    except UnicodeDecodeError:
        raise ValueError(f"config {path}: not a text file (expected UTF-8 YAML)") from None
    except yaml.YAMLError as err:
        where = getattr(err, "problem_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where else ""
        problem = getattr(err, "problem", None) or type(err).__name__
        raise ValueError(f"config {path}: not valid YAML{at}: {problem}") from None
    if data is None or data == {}:
        raise ValueError(f"config {path}: the file is empty (expected a mapping of options)")
    if not isinstance(data, dict):
        raise ValueError(f"config {path}: expected a mapping of options, got {type(data).__name__}")
    return path


def bundled_configs() -> list[str]:
    """Names of the YAML files in :data:`CONFIG_DIR`."""
    return sorted(p.name for p in CONFIG_DIR.glob("*.yaml"))


def resolve_config_args(args: list[str]) -> list[str]:
    """Apply :func:`resolve_config` to ``--config NAME``, ``--config=NAME``, ``-c NAME``."""
    out = list(args)
    for i, arg in enumerate(out):
        if arg in ("--config", "-c") and i + 1 < len(out):
            out[i + 1] = resolve_config(out[i + 1])
        elif arg.startswith("--config="):
            out[i] = "--config=" + resolve_config(arg.split("=", 1)[1])
    return out
