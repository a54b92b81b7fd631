"""Command-line flags generated from config dataclasses, so every option is spelled once.

A config is a ``@dataclass`` whose docstring has an ``Attributes:`` section (one ``name: text`` entry per
field, continuation lines indented deeper). :func:`add_config_arguments` adds one flag per field to an
``argparse`` parser, with the docstring text as help and the field's default; :func:`config_from_args`
builds the dataclass back from the parsed arguments. Field ``metadata`` adjusts a flag:

* ``flag``: the flag name (default ``--field-name``);
* ``choices``: allowed values, or a function returning them when a parser is built (a registry's names, so an
  entry registered after the config class was defined is offered too); ``required``: the flag must be given
  (even though the field has a default);
* ``off_help``: the help of the ``--no-name`` switch of a ``True`` field (default ``turn off: <field text>``);
* ``cli=False``: no flag (the command fills the field itself, e.g. from several flags).

Recipe files (``--config``) and the config overrides of experiment specs are read by the one YAML validator,
:class:`abm.schema.Reader`, each value with its option's own check (:func:`flag_check`, :func:`field_check`).

Numbers are range-checked when the command line is parsed (:func:`int_range`, :func:`float_range`): a
field's ``range`` metadata ``(low, high)`` sets it, else :data:`RANGES` by field name, else whole numbers
are 1 .. 10**9 and reals finite and >= 0. Command modules use the same helpers for their own flags
(:data:`positive_int`, :data:`count`, :data:`seed_int`, :data:`port_number`).

A field whose value is a nested configuration of one of several kinds (a grounder's, a language encoder's:
an object with a ``kind``) is a ``--name KIND`` flag: its ``choices`` metadata comes from the kinds' registry, its
default shows the default's kind, and the parsed value is the kind name (the dataclass reads a name as that kind's
defaults; the command adds the kind's options from its other flags).

Booleans become switches: ``--name`` for a ``False`` default, ``--no-name`` for a ``True`` default.
``list[...]`` and ``tuple[X, ...]`` fields take one or more values, ``tuple[X, X, X]`` exactly three;
``X | None`` fields default to ``None``. With ``overrides_only`` a flag that is not given leaves no value,
so a config whose defaults come from a preset (the policy's) only receives what the user changed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import types
import typing
from pathlib import Path
from typing import Any

from abm.errors import ConfigError
from abm.files import load_yaml
from abm.schema import Check, Mismatch, Reader, boolean, mismatch

# Defaults shared by several commands, defined once here (this module is imported by every command).
CAMERA_RESOLUTION = 128  #: camera image side (px) of demonstrations, evaluation, the quickstart and rollouts
MAX_KEYFRAMES = 8  #: keyframes per evaluation rollout (abm eval, abm quickstart, abm view --task, the scripts)
SPLITS: tuple[str, ...] = ("seen", "unseen", "compositional")  #: the object splits (abm.types.Split), light for parsers
WORKERS = 2  #: parallel processes of data generation, evaluation, the quickstart and abm clip train
CPU_CLIP_MODEL = "openai/clip-vit-base-patch16"  #: the CPU-sized pretrained CLIP (tried first on CPU)
GPU_CLIP_MODEL = "openai/clip-vit-large-patch14-336"  #: the paper's CLIP (the default of the clip grounder)
TEST_ONLY_CLIP = "random weights, for tests only: masks and text features are meaningless"  #: 'tiny' / 'random:*'


def clip_model_help(use: str, default: str | None = GPU_CLIP_MODEL) -> str:
    """The help of a ``--clip-model`` option, the same for every command: what it takes, that 'tiny' and
    'random:ARCH' are random-weight CLIPs for tests only, and the default."""
    shown = f" (default: {default})" if default else ""
    return (f"CLIP weights {use}: a hub name or a local folder (e.g. an abm clip train output); 'tiny' and "
            f"'random:ARCH' are {TEST_ONLY_CLIP}{shown}")

_ENTRY = re.compile(r"^(\s+)([A-Za-z_][\w ,/]*?):\s+(.*)$")

INT_MAX = 10**9  # no count abm takes (steps, episodes, pixels, ...) is anywhere near this
SEED_MAX = 2**32 - 1  # numpy's legacy seeding, which training uses, takes 32 bits


def int_range(low: int | None = 1, high: int | None = INT_MAX) -> Any:
    """An argparse ``type``: a whole number in ``[low, high]``, else a one-line error saying what is expected."""
    expected = (f"a whole number from {low} to {high}" if low is not None and high is not None else
                "a whole number" + (f" >= {low}" if low is not None else "") + (f" <= {high}" if high else ""))

    def parse(text: str) -> int:
        try:
            value = int(str(text).strip().replace("_", ""), 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if (low is not None and value < low) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    parse.__name__ = "int"
    return parse


def float_range(low: float | None = 0.0, high: float | None = None, low_open: bool = False) -> Any:
    """An argparse ``type``: a finite real number in ``[low, high]`` (``low_open``: above ``low``)."""
    bounds = ([f"{'>' if low_open else '>='} {low:g}"] if low is not None else []) + \
        ([f"<= {high:g}"] if high is not None else [])
    expected = "a finite number" + (" " + " and ".join(bounds) if bounds else "")

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not math.isfinite(value) or (low is not None and (value <= low if low_open else value < low)) or \
                (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    parse.__name__ = "float"
    return parse


positive_int = int_range(1)
count = int_range(0)
seed_int = int_range(0, SEED_MAX)
port_number = int_range(1, 65535)

# Ranges of config fields by name, where the default (whole numbers >= 1, reals >= 0) does not fit.
RANGES: dict[str, tuple[float | None, float | None]] = {
    "seed": (0, SEED_MAX), "warmup": (0, INT_MAX), "keep_checkpoints": (0, INT_MAX), "workers": (0, 256),
    "gifs": (0, INT_MAX), "dropout": (0.0, 1.0), "min_lr_ratio": (0.0, 1.0), "workspace_center": (None, None),
}
_POSITIVE_REALS = {"lr", "workspace_size", "mlp_ratio"}


def field_type(f: dataclasses.Field[Any], kind: Any) -> Any:
    """The range-checked argparse ``type`` of a numeric field (``kind`` int or float), see the module docstring."""
    default = (1, INT_MAX) if kind is int else (0.0, None)
    low, high = f.metadata.get("range", RANGES.get(f.name, default))  # None: unbounded on that side
    if kind is int:
        return int_range(low, high)
    if f.name in _POSITIVE_REALS:
        return float_range(0.0, high, low_open=True)
    return float_range(low, high)


def settable_fields(cls: type) -> dict[str, dataclasses.Field[Any]]:
    """The fields of the config dataclass ``cls`` a flag, ``--set`` or a file sets (not ``cli=False``)."""
    return {f.name: f for f in dataclasses.fields(cls) if f.metadata.get("cli", True)}


def field_check(cls: type, name: str) -> Check:
    """The values of the field ``name`` of the config dataclass ``cls`` as a check of :mod:`abm.schema`, the checks
    of its flag: type, range (:func:`field_type`), choices, a list's length; ``None`` where the field may be."""
    f = settable_fields(cls)[name]
    kind, nargs, optional = _base_type(typing.get_type_hints(cls)[name])
    choices = field_choices(f)

    def item(value: Any) -> Any:
        if kind in (int, float):
            if isinstance(value, bool) or not isinstance(value, int | float) or (kind is int and
                                                                                 not isinstance(value, int)):
                raise mismatch("a whole number" if kind is int else "a number", value)
            try:
                return field_type(f, kind)(str(value))
            except argparse.ArgumentTypeError as err:
                raise Mismatch(str(err)) from None
        if choices is not None and isinstance(value, str) and value not in choices:
            raise mismatch(f"one of {', '.join(map(str, choices))}", value)
        if kind in (str, Path) and not isinstance(value, str):
            raise mismatch("a path" if kind is Path else "text", value)
        return value

    def check(value: Any) -> Any:
        if value is None and optional:
            return None
        if kind is bool:
            return boolean(value)
        if nargs is None:
            return item(value)
        if not isinstance(value, list) or (isinstance(nargs, int) and len(value) != nargs) or not value:
            raise mismatch(f"a list of {nargs} values" if isinstance(nargs, int) else "a list of values", value)
        return [item(v) for v in value]

    return check


def check_overrides(cls: type, overrides: dict[str, Any], option: str = "--set") -> dict[str, Any]:
    """``KEY=VALUE`` overrides of the config dataclass ``cls``, checked like its flags (:func:`field_check`).

    Raises:
        ConfigError: an unknown key (the message lists the known ones) or a value of the wrong type or range, or
            not among the field's choices.
    """
    fields = settable_fields(cls)
    out: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in fields:
            raise ConfigError(f"{option} {key}=...: {cls.__name__} has no settable field {key!r}; known: "
                              f"{', '.join(sorted(fields))}")
        try:
            out[key] = field_check(cls, key)(value)
        except Mismatch as err:
            raise ConfigError(f"{option} {key}={value!r}: {err}") from None
    return out


def attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> its text in the class docstring's ``Attributes:`` section (whitespace joined)."""
    doc = cls.__doc__ or ""
    lines = doc.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == "Attributes:")
    except StopIteration:
        return {}
    docs: dict[str, str] = {}
    current: list[str] = []
    indent = None
    for line in lines[start + 1:]:
        if not line.strip():
            if current:
                break
            continue
        m = _ENTRY.match(line)
        if m and (indent is None or len(m.group(1)) == indent):
            indent = len(m.group(1))
            current = [n.strip() for n in re.split(r"[/,]", m.group(2))]
            for name in current:
                docs[name] = m.group(3).strip()
        elif indent is not None and len(line) - len(line.lstrip()) > indent and current:
            for name in current:
                docs[name] += " " + line.strip()
        else:
            break
    return {name: _plain(text) for name, text in docs.items()}


def _plain(text: str) -> str:
    """Docstring markup to plain text: ``code`` -> code, :class:`abm.X` -> X, *word* -> word."""
    text = re.sub(r":\w+:`~?([\w.]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], text)
    return re.sub(r"\*(\w[^*]*?)\*", r"\1", text.replace("``", ""))


def field_choices(f: dataclasses.Field[Any]) -> Any:
    """A field's allowed values (its ``choices`` metadata, called now when it is a function), or ``None``."""
    choices = f.metadata.get("choices")
    return tuple(choices()) if callable(choices) else choices


def flag_value(value: Any) -> Any:
    """What a field's value is on the command line: a nested configuration (an object with a ``kind`` and a
    ``to_dict``) its kind name, anything else itself."""
    kind = getattr(value, "kind", None)
    return kind if isinstance(kind, str) and callable(getattr(value, "to_dict", None)) else value


def _flag(f: dataclasses.Field[Any]) -> str:
    return str(f.metadata.get("flag", "--" + f.name.replace("_", "-")))


def _base_type(annotation: Any) -> tuple[Any, Any, bool]:
    """``(element type, nargs, is_optional)`` of a field annotation (``nargs`` None for a single value)."""
    optional = False
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        optional = len(args) < len(typing.get_args(annotation))
        annotation = args[0] if len(args) == 1 else str
        origin = typing.get_origin(annotation)
    if origin is list:
        (element,) = typing.get_args(annotation) or (str,)
        return element, "+", optional
    if origin is tuple:
        items = typing.get_args(annotation) or (str, ...)
        return items[0], ("+" if len(items) == 2 and items[1] is Ellipsis else len(items)), optional
    return annotation, None, optional


def add_config_arguments(parser: argparse.ArgumentParser, cls: type, defaults: Any | None = None, *,
                         overrides_only: bool = False, exclude: tuple[str, ...] = (), dest_prefix: str = "",
                         title: str | None = None) -> None:
    """Add one flag per field of the dataclass ``cls`` (see module docstring).

    Args:
        parser: where the flags go.
        cls: the config dataclass (its annotations must be resolvable with ``typing.get_type_hints``).
        defaults: an instance whose values become the flags' defaults (default: ``cls()``).
        overrides_only: flags that are not given leave no value (read them with :func:`overrides_from_args`),
            for configs whose defaults come from elsewhere (a preset).
        exclude: fields without a flag.
        dest_prefix: prefix of the parsed attribute names (keeps two configs' fields apart).
        title: put the flags in an argument group with this title.
    """
    docs = attribute_docs(cls)
    hints = typing.get_type_hints(cls)
    defaults = defaults if defaults is not None or overrides_only else cls()
    target = parser.add_argument_group(title) if title else parser
    for f in dataclasses.fields(cls):
        if not f.metadata.get("cli", True) or f.name in exclude:
            continue
        default = flag_value(getattr(defaults, f.name)) if defaults is not None else None
        text = docs.get(f.name, "").replace("%", "%%")  # argparse formats help with %
        kind, nargs, _ = _base_type(hints[f.name])
        kwargs: dict[str, Any] = {"dest": dest_prefix + f.name, "help": text}
        if overrides_only:
            kwargs["default"] = argparse.SUPPRESS
        if kind is bool:
            if overrides_only:  # --name / --no-name, absent when not given
                target.add_argument(_flag(f), action=argparse.BooleanOptionalAction, **kwargs)
                continue
            flag = _flag(f) if not default else f.metadata.get("flag", "--no-" + f.name.replace("_", "-"))
            if default:  # the flag turns the field off: say so, in the flag's own sense
                kwargs["help"] = f.metadata.get("off_help") or f"turn off: {text}"
            target.add_argument(flag, action="store_false" if default else "store_true", default=default, **kwargs)
            continue
        kwargs["type"] = field_type(f, kind) if kind in (int, float) else kind if kind is Path else str
        kwargs["metavar"] = _flag(f).lstrip("-").replace("-", "_").upper()
        if nargs is not None:
            kwargs["nargs"] = nargs
        if "choices" in f.metadata:
            kwargs["choices"] = field_choices(f)
            kwargs.pop("metavar")
        if f.metadata.get("required"):
            kwargs["required"] = True
        elif not overrides_only:
            kwargs["default"] = default
            shown = default if not isinstance(default, list) else " ".join(map(str, default))
            if default is not None and default != [] and "default" not in text:
                kwargs["help"] = f"{text.rstrip('.')} (default: {shown})"
        target.add_argument(_flag(f), **kwargs)


def config_from_args(cls: type, args: argparse.Namespace, **extra: Any) -> Any:
    """Build ``cls`` from parsed arguments; ``extra`` fills (or overrides) fields without a flag."""
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(cls)
              if f.metadata.get("cli", True) and hasattr(args, f.name)}
    values.update(extra)
    return cls(**values)


def overrides_from_args(args: argparse.Namespace, dest_prefix: str) -> dict[str, Any]:
    """The fields given on the command line for flags added with ``overrides_only`` and ``dest_prefix``."""
    return {k[len(dest_prefix):]: v for k, v in vars(args).items() if k.startswith(dest_prefix)}


# ---------------------------------------------------------------------------------------------- recipe files
RECIPES = Path(__file__).parent / "configs"  # the built-in recipes (the repository's configs/ links here)


def builtin_or_file(name: str | Path, folder: Path, kind: str) -> Path:
    """The path itself when it is a file, else the built-in YAML of that name in ``folder``; ``FileNotFoundError``
    naming the built-in ones otherwise (``kind``: what the file is, for the message)."""
    path = Path(name)
    if path.is_file():
        return path
    builtin = folder / (path.name if path.suffix in (".yaml", ".yml") else f"{path.name}.yaml")
    if path.parent == Path(".") and builtin.is_file():
        return builtin
    known = ", ".join(sorted(p.stem for p in folder.glob("*.yaml")))
    raise ConfigError(f"{kind} {name} not found (give a YAML file, or a built-in {kind}: {known})")


def recipe_path(name: str | Path) -> Path:
    """A recipe file: the path itself when it exists, else the built-in recipe of that name
    (``quickstart`` -> ``abm/configs/quickstart.yaml``)."""
    return builtin_or_file(name, RECIPES, "recipe")


def load_recipe(name: str | Path) -> dict[str, Any]:
    """The mapping of a recipe file (see :func:`recipe_path`); :class:`~abm.errors.ConfigError` when it is missing,
    not YAML or not a mapping."""
    path = recipe_path(name)
    data = load_yaml(path, "recipe") or {}
    if not isinstance(data, dict):
        raise ConfigError(f"recipe {path} must be a mapping of option names to values")
    return data


#: options a recipe file may not set, with the reason: a switch that replaces data is given on the command line,
#: every time, never read from a file that may be reused for another run
RECIPE_REFUSED: dict[str, str] = {
    "overwrite": "replacing a run must be asked for on the command line each time (--overwrite), never by a "
                 "file that may be reused; remove the key from the recipe",
}


_SWITCHES = (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse.BooleanOptionalAction)


def recipe_value(action: argparse.Action, value: Any) -> Any:
    """A recipe's ``value`` for the option ``action``, checked as the command line checks it: the option's own
    ``type`` (so the same ranges: ``lr: .inf`` and ``steps: true`` are refused like ``--lr inf`` and
    ``--steps true``), its ``choices``, one value or a list as the option takes, ``true``/``false`` for a switch.

    Raises:
        argparse.ArgumentTypeError: what is expected and what the recipe gave.
    """
    if value is None:
        if action.default is None and not action.required:
            return None
        raise argparse.ArgumentTypeError("expected a value, got null (leave the key out to keep the default)")
    if isinstance(action, _SWITCHES):
        if not isinstance(value, bool):
            raise argparse.ArgumentTypeError(f"expected true or false, got {value!r}")
        return value
    many = action.nargs in ("+", "*") or isinstance(action.nargs, int) or isinstance(action, argparse._AppendAction)
    if not many:
        return _recipe_item(action, value)
    items = value if isinstance(value, list) else [value]
    if isinstance(action.nargs, int) and len(items) != action.nargs:
        raise argparse.ArgumentTypeError(f"expected a list of {action.nargs} values, got {value!r}")
    if action.nargs == "+" and not items:
        raise argparse.ArgumentTypeError("expected at least one value, got an empty list")
    return [_recipe_item(action, item) for item in items]


def _recipe_item(action: argparse.Action, value: Any) -> Any:
    if isinstance(value, dict | list):
        raise argparse.ArgumentTypeError(f"expected one value, got {value!r}")
    if isinstance(value, bool):  # YAML's true/yes/on: never a number, a path or a name
        if callable(action.type) and action.type not in (str, Path):
            try:  # the option's own words for what it expects
                action.type(str(value).lower())
            except argparse.ArgumentTypeError:
                raise
            except (TypeError, ValueError):
                pass
        raise argparse.ArgumentTypeError(f"expected {_expected(action)}, got {str(value).lower()}")
    text = value if isinstance(value, str) else str(value)
    try:
        converted = action.type(text) if callable(action.type) and action.type is not str else text
    except argparse.ArgumentTypeError:
        raise
    except (TypeError, ValueError) as err:
        raise argparse.ArgumentTypeError(f"expected {_expected(action)}, got {value!r} ({err})") from None
    if action.choices is not None and converted not in action.choices:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(map(str, action.choices))}, got {value!r}")
    return converted


def _expected(action: argparse.Action) -> str:
    name = getattr(action.type, "__name__", "")
    return {"int": "a whole number", "float": "a number"}.get(name, "a path" if action.type is Path else "text")


def apply_config_file(parser: argparse.ArgumentParser, argv: list[str]) -> None:
    """Make the values of ``--config FILE`` the defaults of the command it is given to, so flags override it.

    Only for commands with a ``--config`` option. The file maps option names (``lr``, ``checkpoint_every`` or
    ``checkpoint-every``) to values; a nested mapping fills the options whose destination starts with the
    command's ``config_sections[name]`` prefix (``policy:`` -> the policy flags). Options the file sets are no
    longer required on the command line. The file is read by the YAML validator (:func:`check_recipe`), every value
    with the checks its flag has (:func:`flag_check`: the same ranges, choices and types). Bad files end the command
    with a usage error naming the file, the key and what is expected, and so do the keys of :data:`RECIPE_REFUSED`
    (``overwrite``) and an empty path.
    """
    sub, tokens = parser, list(argv)
    while True:  # descend to the (sub-)command the arguments name
        choices = next((a.choices for a in sub._actions if isinstance(a, argparse._SubParsersAction)), None)
        index = next((i for i, t in enumerate(tokens) if choices and t in choices), None)
        if index is None or choices is None:
            break
        sub, tokens = choices[tokens[index]], tokens[index + 1:]
    if "--config" not in sub._option_string_actions:
        return
    given = [tokens[i + 1] for i, t in enumerate(tokens[:-1]) if t == "--config"]
    given += [t.split("=", 1)[1] for t in tokens if t.startswith("--config=")]
    if not given:
        return
    try:
        values = load_recipe(given[-1])
        checked = check_recipe(sub, values, f"recipe {given[-1]}")
    except ConfigError as err:  # not found, not YAML, not a mapping, a bad value: the message names the file
        sub.error(str(err))
    for action, v in checked:
        action.default = v
        action.required = False


def flag_check(action: argparse.Action, flag: str | None = None, fix: str = "") -> Check:
    """The values of the option ``action`` as a check of :mod:`abm.schema` (what a recipe or a spec gives for it):
    :func:`recipe_value`, whose words name ``flag`` (default: the option's first flag) as the same check, then
    ``fix``."""
    same = flag or (action.option_strings[0] if action.option_strings else action.dest)

    def check(value: Any) -> Any:
        try:
            return recipe_value(action, value)
        except argparse.ArgumentTypeError as err:
            raise Mismatch(f"{err} (the same check as {same}){fix}") from None

    return check


def check_recipe(parser: argparse.ArgumentParser, values: dict[str, Any], source: str
                 ) -> list[tuple[argparse.Action, Any]]:
    """Every value of a recipe for the command ``parser`` (``abm train``), checked as its flag checks it
    (:func:`flag_check`, read by the YAML validator :class:`abm.schema.Reader`), with the option it sets; what
    ``abm train --config`` and an experiment spec's recipe (:mod:`abm.experiments.spec`) both check before
    anything runs. A section (``policy:``, the command's ``config_sections``) holds the options of its prefix.

    Raises:
        ConfigError: ``SOURCE: KEY: what is expected (the same check as --FLAG); fix the value in the recipe``;
            an unknown option (``unknown keys [...] (expected: [...])``), a key of :data:`RECIPE_REFUSED`, an empty
            path.
    """
    sections: dict[str, str] = parser.get_default("config_sections") or {}
    actions = {a.dest: a for a in parser._actions if a.dest not in ("help", "config")}
    top = Reader(values, source, error=ConfigError)
    own = {dest: a for dest, a in actions.items() if not any(dest.startswith(p) for p in sections.values())}
    checked = _options(top, own)
    top.done([*own, *sections])
    for section, prefix in sections.items():
        if top.has(section):
            reader = top.sub(section)
            options = {dest.removeprefix(prefix): a for dest, a in actions.items() if dest.startswith(prefix)}
            checked += _options(reader, options)
            reader.done(list(options))
    return checked


def _options(reader: Reader, options: dict[str, argparse.Action]) -> list[tuple[argparse.Action, Any]]:
    """The values of ``reader`` that set ``options`` (by name; ``-`` may stand for ``_``), each checked."""
    checked = []
    for key in list(reader.data):
        name = str(key).replace("-", "_")
        if name not in options:
            continue
        if name in RECIPE_REFUSED:
            raise reader.error(f"{key!r} cannot be set in a recipe: {RECIPE_REFUSED[name]}")
        value = reader.data[key]
        if options[name].type is Path and isinstance(value, str) and not value.strip():
            raise reader.error(f"{key} is an empty path; give a path, or leave the key out")
        checked.append((options[name], reader.value(key, flag_check(options[name],
                                                                    fix="; fix the value in the recipe"))))
    return checked
