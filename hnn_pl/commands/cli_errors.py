"""The CLI's error layer: every refusal is one line, and comes before any work.

- :func:`one_line`: jsonargparse's nested, multi-line parse errors (and its usage dump)
  as one line naming the option, with the closest valid names (``did you mean …?``);
  class names are resolved only among the modules already imported.
- :func:`check_ckpt_path`, :func:`given_model_options`: for a ``--ckpt_path``,
  compared with the config by :mod:`hnn_pl.safe_io`.
- :func:`check_starts`, :func:`check_trainer_numbers`, :func:`check_threads`: a
  ``predict`` file of starts (or of positions windows), the trainer's numbers
  Lightning takes unchecked, and ``--threads`` (the plain commands' numbers:
  :mod:`hnn_pl.argtypes`).
- :func:`user_error`: the one line an exception gives, or ``None`` for a bug.
"""

from __future__ import annotations

import argparse
import difflib
import inspect
import math
import pickle
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hnn_pl.argtypes import _INTEGER


def program_name() -> str:
    """``hnn-pl`` when run as the console script, else ``python -m hnn_pl``."""
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return "hnn-pl" if name.startswith("hnn-pl") else "python -m hnn_pl"


class CLIError(ValueError):
    """Bad command-line input: printed as one line, exit status 2."""


#: what bad input raises (pickle's: a checkpoint that is more than weights); anything
#: else is a bug and keeps its traceback
USER_ERRORS = (ValueError, OSError, FloatingPointError, pickle.UnpicklingError)


def user_error(err: BaseException) -> str | None:
    """The message of the innermost bad-input exception behind ``err`` (jsonargparse
    wraps an ``__init__``'s), or ``None``."""
    found, seen = None, set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, USER_ERRORS):
            found = err
        err = err.__cause__ or (None if err.__suppress_context__ else err.__context__)
    if found is None:
        return None
    return (str(found).strip().splitlines() or [type(found).__name__])[0]


class OneLineParser(argparse.ArgumentParser):
    """argparse for the plain commands (``reproduce``, ``bump``, ``stress``): a bad
    option is a one-line :class:`CLIError` (``--x must be …``), no usage dump."""

    def error(self, message: str):
        message = re.sub(r"^argument (\S+): (must )", r"\1 \2", message)
        raise CLIError(re.sub(r"^argument (\S+): ", r"\1: ", message))


#: trainer counts Lightning takes unchecked (a 0 divides by zero, a negative one is read
#: as another): name -> least value
TRAINER_COUNTS = {
    "check_val_every_n_epoch": 1,
    "accumulate_grad_batches": 1,
    "log_every_n_steps": 0,
    "num_sanity_val_steps": -1,
    "min_steps": 0,
    "min_epochs": 0,
}


def check_trainer_numbers(trainer: Mapping[str, Any]) -> None:
    """Refuse, naming the option, a trainer count below :data:`TRAINER_COUNTS`, a
    ``val_check_interval`` not finite and > 0, a ``gradient_clip_val`` not finite and
    >= 0."""
    for name, least in TRAINER_COUNTS.items():
        value = trainer.get(name)
        if value is not None and value < least:
            raise CLIError(f"trainer.{name} must be an integer >= {least}, got {value}")
    interval = trainer.get("val_check_interval")
    if interval is not None and not (math.isfinite(interval) and interval > 0):
        raise CLIError(f"trainer.val_check_interval must be a number > 0, got {interval}")
    clip = trainer.get("gradient_clip_val")
    if clip is not None and not (math.isfinite(clip) and clip >= 0):
        raise CLIError(f"trainer.gradient_clip_val must be a finite number >= 0, got {clip}")


def did_you_mean(word: str, candidates: list[str] | set[str], prefix: str = "") -> str:
    """``"; did you mean X?"`` (or ``"X or Y?"``) for the closest candidates, else ``""``."""
    ratio = lambda c: difflib.SequenceMatcher(None, word, c).ratio()  # noqa: E731
    scored = sorted(((ratio(c), c) for c in set(candidates)), reverse=True)
    close = [c for r, c in scored[:2] if r >= 0.6 and r >= scored[0][0] - 0.1]
    if not close:
        return ""
    return "; did you mean " + " or ".join(prefix + c for c in close) + "?"


def init_parameters(cls: type) -> list[str]:
    """Named parameters of ``cls(...)``, following ``**kwargs`` up the MRO."""
    names: list[str] = []
    for klass in cls.__mro__:
        init = vars(klass).get("__init__")
        if init is None:
            continue
        params = inspect.signature(init).parameters.values()
        names += [p.name for p in params if p.name != "self" and p.kind not in (2, 4)]
        if not any(p.kind == p.VAR_KEYWORD for p in params):
            break
    return list(dict.fromkeys(names))


_NOISE = (
    "Does not validate against",
    "Subtypes:",
    "Errors:",
    "- Expected a <class 'NoneType'>",
    "Given value",
    "- Expected a path but",
    "Parser key",
    "Problem with given class_path",
)


def one_line(message: str, parser: Any = None) -> str:
    """jsonargparse's error ``message`` as one line, with suggestions from ``parser``'s
    options or from the classes already imported."""
    text = message.strip()
    unknown = re.match(r"unrecognized arguments: (.*)", text)
    if unknown:
        given = [a.split("=")[0] for a in unknown.group(1).split() if a.startswith("-")]
        option = given[0] if given else unknown.group(1)
        return f"unknown option {option}" + did_you_mean(option, _option_strings(parser))
    keys = re.findall(r'Parser key "([^"]+)"', text)
    key = ".".join(keys) + ": " if keys else ""
    classes = re.findall(r"Problem with given class_path '([^']+)'", text)
    option = re.search(r"Option '([^']+)' is not accepted", text)
    if option:
        owner = classes[-1] if classes else "the class"
        from hnn_pl.safe_io import loaded_class  # torch: only once a class is named

        cls = loaded_class(owner) if classes else None
        names = init_parameters(cls) if cls is not None else []
        return f"{key}{owner} has no option {option.group(1)!r}" + did_you_mean(
            option.group(1), names
        )
    missing = re.search(r"module '([^']+)' has no attribute '([^']+)'", text)
    if missing:
        module, name = missing.groups()
        found = _public_classes(module)
        return f"{key}no class {name} in {module}" + did_you_mean(name, found, module + ".")
    short = re.search(r"Expected a dot import path string: (\S+)", text)
    if short:
        name = short.group(1)
        return f"{key}unknown class {name!r}" + did_you_mean(name, _known_class_names())
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    useful = [line for line in lines if not line.startswith(_NOISE)]
    detail = (useful or lines or [type(message).__name__])[-1].lstrip("- ")
    detail = re.sub(
        r"Expected a <class '(\w+)'>\. Got value: (.*)", r"expected \1, got '\2'", detail
    )
    where = f" (class path {classes[-1]})" if classes and "No module named" in detail else ""
    if detail.startswith("Unexpected config"):
        detail = "the config has no options" if detail.endswith(":") else detail
    return f"{key}{detail}{where}"


def _public_classes(module: str) -> list[str]:
    """The public class names of ``module``, if it is imported."""
    items = vars(sys.modules.get(module, object)).items()
    return [n for n, v in items if isinstance(v, type) and not n.startswith("_")]


def _known_class_names() -> set[str]:
    """Short names of the classes of the packages the CLI registers."""
    packages = ("hnn_pl.models", "hnn_pl.data", "hnn_pl.systems", "hnn_pl.callbacks")
    return {name for package in packages for name in _public_classes(package)}


def _option_strings(parser: Any) -> set[str]:
    """Every long option of ``parser`` and of its subcommands' parsers."""
    found: set[str] = set()
    stack = [parser] if parser is not None else []
    while stack:
        p = stack.pop()
        for action in getattr(p, "_actions", []):
            found |= {s for s in action.option_strings if s.startswith("--")}
            choices = getattr(action, "choices", None)
            if isinstance(choices, dict):
                stack += [c for c in choices.values() if hasattr(c, "_actions")]
    return found


def check_ckpt_path(ckpt_path: str | None) -> bool:
    """Whether ``ckpt_path`` names a file to check; a missing one is a :class:`CLIError`."""
    from hnn_pl.loggers import SPECIAL_CKPT_PATHS

    if not ckpt_path or ckpt_path in SPECIAL_CKPT_PATHS or str(ckpt_path).startswith("registry"):
        return False
    if not Path(ckpt_path).exists():
        raise CLIError(f"checkpoint {ckpt_path}: no such file")
    return True


def given_model_options(argv: list[str]) -> set[str]:
    """The model options set on the command line ``argv``: ``--model.init_args.lr=0.5``,
    ``--model.init_args.lr 0.5`` or ``--model.lr=0.5`` give ``lr``."""
    found = set()
    for arg in argv:
        m = re.fullmatch(r"--model\.(?:init_args\.)?(\w+)(=.*)?", arg, re.S)
        if m and m.group(1) not in ("help", "class_path", "init_args", "dict_kwargs"):
            found.add(m.group(1))
    return found


def check_starts(path: str, width: int) -> None:
    """:func:`hnn_pl.callbacks.check_starts_file` before any data or directory is made,
    its refusal as one line."""
    from hnn_pl.callbacks import check_starts_file

    try:
        check_starts_file(path, width)
    except ValueError as err:
        raise CLIError(str(err)) from None


def check_threads(requested: Any) -> int | None:
    """``--threads``: ``None`` for ``"auto"``/unset, else a plain integer >= 1 (``1.5``,
    ``1_5``, ``nan`` refused, naming the option)."""
    if requested in (None, "auto"):
        return None
    text = str(requested)
    valid = not isinstance(requested, bool) and _INTEGER.fullmatch(text) and int(text) >= 1
    if not valid:
        raise CLIError(f"--threads must be >= 1 or 'auto', got {requested!r}")
    return int(text)
