"""The CLI's error layer: every refusal is one line, and comes before any work.

- :func:`one_line`: jsonargparse's nested, multi-line parse errors (and its usage
  dump) become one line naming the option, with the closest valid names
  (``did you mean hidden_dim?``).
- a ``--ckpt_path`` is read as data (:func:`hnn_pl.safe_io.load_checkpoint`) and the
  model class it names is compared *as a string* with the class the config builds
  (:func:`hnn_pl.safe_io.check_model_class`); nothing a checkpoint names is imported.
- :func:`checkpoint_init_args`: the plain hyperparameters of a checkpoint that the
  config's class takes (what LightningCLI restores, without resolving a class path);
  :func:`refuse_changed_options`: an option given on the command line (or the
  objective) that differs from the checkpoint's is refused, never silently replaced.
- :func:`check_starts`: a ``predict`` file of starts is a finite ``(B, D)`` tensor,
  or a positions window the observer infers the starts from.
- the plain commands' numeric options are read by type functions (:func:`positive_int`,
  :func:`finite_float`, …) that refuse a value out of range, non-finite or not plainly
  written (``1_5``, ``0x10``) at parse time, naming the option; the trainer's numbers
  that Lightning takes unchecked are checked by :func:`check_trainer_numbers`.
- :func:`user_error`: the one line an exception gives, or ``None`` for a bug.

Class names are resolved only among modules already imported (the config's classes,
imported when the config was parsed): see :func:`hnn_pl.safe_io.loaded_class`.
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


#: ``ckpt_path`` values Lightning resolves itself (not files)
SPECIAL_CKPT_PATHS = ("last", "best", "hpc")


class CLIError(ValueError):
    """Bad command-line input: printed as one line, exit status 2."""


#: what bad input raises (pickle's: a checkpoint that is more than weights); anything
#: else is a bug and keeps its traceback
USER_ERRORS = (ValueError, OSError, FloatingPointError, pickle.UnpicklingError)


def user_error(err: BaseException) -> str | None:
    """The message of the innermost bad-input exception behind ``err`` (jsonargparse
    wraps the one an ``__init__`` raised), or ``None`` if there is none."""
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
    option is a :class:`CLIError`, printed by ``__main__`` as one line, no usage dump;
    argparse's ``argument --x: must be …`` reads ``--x must be …``."""

    def error(self, message: str):
        message = re.sub(r"^argument (\S+): (must )", r"\1 \2", message)
        raise CLIError(re.sub(r"^argument (\S+): ", r"\1: ", message))


# ------------------------------------------------------------------ option values

_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def finite_float(text: str) -> float:
    """An argparse ``type``: a plain decimal number that is finite as a float (``nan``,
    ``inf``, ``1e999``, ``1_5`` refused)."""
    value = float(text) if _DECIMAL.fullmatch(text) else math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """An argparse ``type``: a finite number ``> 0`` (a horizon, a step)."""
    value = float(text) if _DECIMAL.fullmatch(text) else math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def output_directory(text: str) -> Path:
    """An argparse ``type``: a directory to write into, absent (made when written) or a
    directory; a path naming a file, or below one, is refused."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a file; name a directory to write into")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{text}: {parent} is not a directory")
            break
    return path


#: trainer options Lightning takes without a check (a 0 divides by zero at the first
#: step, a negative count is silently read as another): name -> least value
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
    ``val_check_interval`` that is not a finite number > 0 and a ``gradient_clip_val``
    that is not finite and >= 0 (``None``: Lightning's default)."""
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
    scored = sorted((difflib.SequenceMatcher(None, word, c).ratio(), c) for c in set(candidates))[
        ::-1
    ]
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


# --------------------------------------------------------------------- parse errors

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
        found = [n for n, v in vars(sys.modules.get(module, object)).items() if _public_class(n, v)]
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


def _public_class(name: str, value: Any) -> bool:
    return isinstance(value, type) and not name.startswith("_")


def _known_class_names() -> set[str]:
    """Short names of the classes of the packages the CLI registers."""
    names: set[str] = set()
    for package in ("hnn_pl.models", "hnn_pl.data", "hnn_pl.systems", "hnn_pl.callbacks"):
        names |= {
            n for n, v in vars(sys.modules.get(package, object)).items() if _public_class(n, v)
        }
    return names


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


# ------------------------------------------------------------------- checkpoints


def check_ckpt_path(ckpt_path: str | None) -> bool:
    """Whether ``ckpt_path`` names a file to check; a missing one is a :class:`CLIError`."""
    if not ckpt_path or ckpt_path in SPECIAL_CKPT_PATHS or str(ckpt_path).startswith("registry"):
        return False
    if not Path(ckpt_path).exists():
        raise CLIError(f"checkpoint {ckpt_path}: no such file")
    return True


def _plain(value: Any) -> bool:
    if isinstance(value, (list, tuple)):
        return all(_plain(v) for v in value)
    return value is None or isinstance(value, (bool, int, float, str))


#: model options a checkpoint never restores: linked from the data, or about the run
#: itself (``reinit_states``: what a resumed fit does with learned states)
NOT_RESTORED = ("input_dim", "reinit_states")
#: model options whose checkpoint value must be the config's: restoring it silently
#: would make the model refuse the config's data
MUST_MATCH = ("objective",)


def given_model_options(argv: list[str]) -> set[str]:
    """The model options set on the command line ``argv``: ``--model.init_args.lr=0.5``,
    ``--model.init_args.lr 0.5`` or ``--model.lr=0.5`` give ``lr``."""
    found = set()
    for arg in argv:
        m = re.fullmatch(r"--model\.(?:init_args\.)?(\w+)(=.*)?", arg, re.S)
        if m and m.group(1) not in ("help", "class_path", "init_args", "dict_kwargs"):
            found.add(m.group(1))
    return found


def checkpoint_init_args(
    ckpt: dict[str, Any], init_args: Any, given: set[str] | frozenset[str] = frozenset()
) -> dict[str, Any]:
    """The checkpoint's hyperparameters that restore the config's ``init_args``: keys the
    config already has with a plain value, given plain values (never a class path),
    except :data:`NOT_RESTORED` and the options ``given`` on the command line (which
    :func:`refuse_changed_options` has compared)."""
    hparams = ckpt.get("hyper_parameters") or {}
    current = vars(init_args) if init_args is not None and hasattr(init_args, "__dict__") else {}
    return {
        k: v
        for k, v in hparams.items()
        if k in current
        and k not in NOT_RESTORED
        and k not in given
        and _plain(v)
        and _plain(current[k])
    }


def refuse_changed_options(
    ckpt: dict[str, Any], init_args: Any, given: set[str], where: str
) -> None:
    """A run from a checkpoint keeps the options it was trained with: a model option
    ``given`` on the command line with another value than the checkpoint's, or one of
    :data:`MUST_MATCH` that the config sets otherwise, is a :class:`CLIError` naming
    both values (never silently replaced; :data:`NOT_RESTORED` excepted)."""
    hparams = ckpt.get("hyper_parameters") or {}
    current = vars(init_args) if init_args is not None and hasattr(init_args, "__dict__") else {}
    for k in [*sorted(given), *MUST_MATCH]:
        if k in NOT_RESTORED or k not in hparams or k not in current:
            continue
        saved, value = hparams[k], current[k]
        if not (_plain(saved) and _plain(value)) or _same(saved, value):
            continue
        if k in given:
            raise CLIError(
                f"--model.init_args.{k}={value}: {where} was trained with {k}={saved!r}, and "
                "a run from a checkpoint keeps the options it was trained with: remove the "
                "option, or fit anew without --ckpt_path"
            )
        raise CLIError(
            f"{where} was trained with {k}={saved!r} but the config sets {k}: {value!r}: use "
            "the config the checkpoint was trained with"
        )


def _same(a: Any, b: Any) -> bool:
    """Equal plain values, a list equal to a tuple of the same items."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return list(a) == list(b)
    return a == b


# ------------------------------------------------------------------------ starts


def check_starts(path: str, width: int) -> None:
    """Refuse a ``predict`` file of starts that is missing, not a tensor, not
    ``(B, width)`` or not finite, before any data or directory is made; or, for a
    positions window (a ``.csv`` or a saved dict, :func:`~hnn_pl.evaluation.observer.
    read_positions_window`), one the observer cannot read with ``k = width / 2``."""
    if not Path(path).is_file():
        raise CLIError(f"starts {path}: no such file")
    import torch

    if Path(path).suffix == ".csv":
        return _check_window(path, width)
    try:
        y0 = torch.load(path, weights_only=True, map_location="cpu")
    except Exception:  # noqa: BLE001 - any unreadable file is the same user error
        raise CLIError(f"starts {path}: cannot be read as a torch-saved tensor") from None
    if isinstance(y0, dict):
        return _check_window(path, width)
    if not torch.is_tensor(y0) or not y0.is_floating_point():
        kind = f"{y0.dtype} tensor" if torch.is_tensor(y0) else type(y0).__name__
        raise CLIError(
            f"starts {path}: holds a {kind}; expected a float tensor (B, {width}) or a "
            f'positions window {{"q": (B, M, {width // 2}), "t": (M,)}}'
        )
    if y0.ndim != 2 or y0.shape[1] != width or y0.shape[0] == 0:
        raise CLIError(
            f"starts {path}: shape {tuple(y0.shape)}; the model's states need (B, {width})"
        )
    bad = ~torch.isfinite(y0).all(-1)
    if bool(bad.any()):
        rows = bad.nonzero().flatten().tolist()
        raise CLIError(
            f"starts {path}: {len(rows)} of {y0.shape[0]} rows are not finite (rows "
            f"{rows[:5]}{'...' if len(rows) > 5 else ''})"
        )


def _check_window(path: str, width: int) -> None:
    """:func:`check_starts` for a positions window: its reader's refusal, one line."""
    from hnn_pl.evaluation.observer import read_positions_window

    try:
        read_positions_window(path, width // 2)
    except ValueError as err:
        raise CLIError(str(err)) from None


def check_threads(requested: Any) -> int | None:
    """``--threads``: ``None`` for ``"auto"``/unset, else an integer >= 1 (a plain one:
    ``1.5``, ``1_5``, ``nan`` refused), else :class:`CLIError` naming the option."""
    if requested in (None, "auto"):
        return None
    text = str(requested)
    valid = not isinstance(requested, bool) and _INTEGER.fullmatch(text) and int(text) >= 1
    if not valid:
        raise CLIError(f"--threads must be >= 1 or 'auto', got {requested!r}")
    return int(text)
