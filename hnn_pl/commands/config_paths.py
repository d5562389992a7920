"""Finding configs: a path, or a bare name looked up in the bundled configs (the
repository's ``configs/``, shipped as the package ``hnn_pl.configs``).

A config may name another as its ``base:`` (a path beside it, or a bundled config's
name) and hold only what differs: ``--config child.yaml`` is read as ``--config <base>
--config <child without base>``, the later applied over the earlier by jsonargparse
(mappings merge key by key, a list or value replaces the base's). Bases chain. No
heavy imports: ``python -m hnn_pl --help`` stays instant.
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
    """A config path as given if it exists, else ``<bundled configs>/<name>[.yaml]``;
    ``FileNotFoundError`` naming the bundled configs, or ``ValueError`` for a file that
    is not a YAML mapping."""
    if Path(name).is_file():
        load_config_file(name)  # a YAML mapping, else one line naming the fault
        return name
    bundled = _bundled(name)
    if bundled is None:
        raise FileNotFoundError(f"config {name!r} is neither a file nor " + _suggest(name))
    return bundled


def _bundled(name: str) -> str | None:
    """``<bundled configs>/<name>[.yaml]`` if it exists."""
    for candidate in (CONFIG_DIR / name, CONFIG_DIR / f"{name}.yaml"):
        if candidate.is_file():
            return str(candidate)
    return None


def _suggest(name: str) -> str:
    """``a bundled config; did you mean X?``, or the list of the bundled configs."""
    import difflib

    names = bundled_configs()
    stems = {Path(n).stem: n for n in names}
    close = difflib.get_close_matches(Path(name).name, [*names, *stems], n=1, cutoff=0.6)
    if close:
        return f"a bundled config; did you mean {stems.get(close[0], close[0])}?"
    return "one of the bundled configs: " + ", ".join(names)


def load_config_file(path: str) -> dict:
    """The YAML mapping in ``path``; else ValueError naming the file and the fault."""
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
    return data


def config_chain(path: str) -> list[tuple[str, dict]]:
    """``(path, mapping)`` of the config at ``path`` and of its bases, the first base
    first, each without its ``base`` key; ``ValueError`` for a base that is not a
    config name, is not found, or closes a cycle."""
    chain: list[tuple[str, dict]] = []
    while True:
        data = dict(load_config_file(path))
        chain.insert(0, (path, data))
        base = data.pop("base", None)
        if base is None:
            return chain
        if not isinstance(base, str) or not base:
            raise ValueError(f"config {path}: base must be a config's path or name, got {base!r}")
        path = _resolve_base(base, path)
        if any(Path(path).resolve() == Path(seen).resolve() for seen, _ in chain):
            cycle = " -> ".join([*(p for p, _ in reversed(chain)), path])
            raise ValueError(f"config {chain[-1][0]}: its bases form a cycle: {cycle}")


def _resolve_base(base: str, config: str) -> str:
    """``base`` beside ``config`` if that file exists, else a bundled config's name."""
    beside = Path(config).parent / base
    found = str(beside) if beside.is_file() else _bundled(base)
    if found is None:
        raise ValueError(
            f"config {config}: base {base!r} is neither a file beside it nor " + _suggest(base)
        )
    return found


def expand_config(name: str) -> list[str]:
    """The ``--config`` values that build config ``name``: its resolved path, or, when it
    names a base, its chain's paths and YAML texts (a config with a ``base`` as its
    mapping without that key), the first base first."""
    import yaml

    path = resolve_config(name)
    chain = config_chain(path)
    if len(chain) == 1:
        return [path]
    values = [chain[0][0]]
    for _, data in chain[1:]:
        if data:
            values.append(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    return values


def bundled_configs() -> list[str]:
    """Names of the YAML files in :data:`CONFIG_DIR`."""
    return sorted(p.name for p in CONFIG_DIR.glob("*.yaml"))


def resolve_config_args(args: list[str]) -> list[str]:
    """Apply :func:`expand_config` to ``--config NAME``, ``--config=NAME``, ``-c NAME``:
    each becomes one ``--config`` per file of its chain."""
    out: list[str] = []
    rest = list(args)
    while rest:
        arg = rest.pop(0)
        if arg in ("--config", "-c") and rest:
            name = rest.pop(0)
        elif arg.startswith("--config="):
            name = arg.split("=", 1)[1]
        else:
            out.append(arg)
            continue
        for value in expand_config(name):
            out += ["--config", value]
    return out
