"""Typed run configs: dataclass <-> command line <-> JSON, and model configs read from a
model's signature.

Help text comes from one place, the class docstring: a Google-style ``Attributes:``
(dataclasses) or ``Args:`` (model classes) section, one entry per field; an entry may
name several fields (``lr, weight_decay: ...``). Every flag shows its default.

Field types the command line understands: ``int``, ``float``, ``str``, ``bool``
(``--x`` / ``--no-x``), ``Literal[...]`` (choices), ``X | None`` (the word ``none`` gives
None), ``tuple[int, ...]`` / ``Sequence[int]`` (comma-separated), ``dict`` (JSON), and a
nested dataclass, whose fields become ``--name.field`` flags (``--model.base-channels``).

Example:
    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class Run:
    ...     "A run.\\n\\nAttributes:\\n    steps: optimizer steps.\\n    widths: channels per level."
    ...     steps: int = 10
    ...     widths: tuple[int, ...] = (8, 16)
    >>> parse(Run, ["--steps", "3", "--widths", "4,8,16"])
    Run(steps=3, widths=(4, 8, 16))
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import re
import sys
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any

__all__ = [
    "field_help",
    "model_config",
    "build_parser",
    "parse",
    "to_dict",
    "from_dict",
    "config_of",
    "differences",
]

_SECTION = re.compile(r"^(Attributes|Args|Arguments|Parameters):\s*$")
_ENTRY = re.compile(r"^(\w+(?:\s*,\s*\w+)*)\s*(?:\([^)]*\))?\s*:\s*(.*)$")


# --------------------------------------------------------------------------- help text
def field_help(cls: type) -> dict[str, str]:
    """``{field: help}`` from the ``Attributes:`` / ``Args:`` section of ``cls``'s docstring.

    Continuation lines (indented deeper than the entry) are joined with spaces; ``x``
    in double backticks is shown as x. An entry ``a, b: text`` gives both fields the text.
    """
    doc = inspect.cleandoc(cls.__doc__ or "")
    found: dict[str, str] = {}
    lines = doc.splitlines()
    i = 0
    while i < len(lines):
        if not _SECTION.match(lines[i]):
            i += 1
            continue
        i += 1
        indent: int | None = None
        names: list[str] = []
        text: list[str] = []
        while i < len(lines):
            line = lines[i]
            stripped = line.strip()
            depth = len(line) - len(line.lstrip())
            if stripped and indent is not None and depth < indent or stripped and indent is None and depth == 0:
                break  # the section ended (a dedent, or an unindented line)
            match = _ENTRY.match(stripped) if stripped and (indent is None or depth == indent) else None
            if match is not None:
                _store(found, names, text)
                indent = depth
                names = [n.strip() for n in match.group(1).split(",")]
                text = [match.group(2)]
            elif stripped:
                text.append(stripped)
            i += 1
        _store(found, names, text)
    return found


def _store(found: dict[str, str], names: list[str], text: list[str]) -> None:
    help_text = " ".join(" ".join(text).split()).replace("``", "")
    for name in names:
        found.setdefault(name, help_text)


# --------------------------------------------------------------------------- model configs
def model_config(
    model_cls: type,
    *,
    name: str,
    exclude: Sequence[str] = (),
    help_from: type | None = None,
    defaults: Mapping[str, Any] | None = None,
    module: str | None = None,
) -> type:
    """A frozen dataclass whose fields are ``model_cls``'s constructor arguments.

    The model's signature stays the only copy of the architecture's names, types and
    defaults (with diffusers' ``@register_to_config`` it is also what ``config.json``
    holds); a trainer nests this dataclass as its ``model`` field, which gives the
    ``--model.x`` flags and the architecture's record in a checkpoint.

    Args:
        model_cls: a class whose ``__init__`` takes keyword arguments with defaults (a
            ``ModelMixin, ConfigMixin`` network, or a dataclass).
        name: the dataclass's name (e.g. ``"EstimatorModelConfig"``).
        exclude: arguments left out (each must exist).
        help_from: the class whose docstring documents the arguments (default:
            ``model_cls``; see ``field_help``).
        defaults: field defaults that differ from the signature's, e.g. what a new training
            run builds where the signature keeps the behaviour of old checkpoints (each
            must name an argument).
        module: ``__module__`` of the new class (pass the caller's ``__name__``).

    ``Sequence[int]`` annotations become ``tuple[int, ...]``; lists (from JSON) given for
    tuple fields are converted to tuples, so configs compare equal across a save.
    """
    if dataclasses.is_dataclass(model_cls):
        hints = typing.get_type_hints(model_cls)
    else:
        hints = typing.get_type_hints(model_cls.__init__)  # type: ignore[misc]  # the class's own constructor
    params = [p for p in inspect.signature(model_cls).parameters.values() if p.kind is not p.VAR_KEYWORD]
    unknown = set(exclude) - {p.name for p in params}
    if unknown:
        raise ValueError(f"{model_cls.__name__} has no arguments {sorted(unknown)} to exclude")
    defaults = dict(defaults or {})
    unknown = set(defaults) - {p.name for p in params if p.name not in exclude}
    if unknown:
        raise ValueError(f"{model_cls.__name__} has no arguments {sorted(unknown)} to give defaults")
    docs = field_help(help_from or model_cls)
    fields: list[tuple[str, Any, Any]] = []
    entries: list[str] = []
    for p in params:
        if p.name in exclude:
            continue
        if p.default is inspect.Parameter.empty:
            raise TypeError(f"{model_cls.__name__}.{p.name} has no default; a model config needs one for every field")
        tp = _normalise(hints.get(p.name, type(p.default)))
        default = defaults.get(p.name, p.default)
        if isinstance(default, (list, dict, set)):
            fields.append((p.name, tp, dataclasses.field(default_factory=_copier(default))))
        else:
            fields.append((p.name, tp, dataclasses.field(default=default)))
        if p.name in docs:
            entries.append(f"    {p.name}: {docs[p.name]}")
    doc = f"Architecture of ``{model_cls.__name__}`` (its constructor's arguments).\n\nAttributes:\n" + "\n".join(
        entries
    )
    cls = dataclasses.make_dataclass(name, fields, frozen=True, namespace={"__post_init__": _tuples_post_init})
    cls.__doc__ = doc
    if module is not None:
        cls.__module__ = module
    return cls


def _copier(value: list | dict | set) -> Callable[[], Any]:
    """A default factory returning a fresh copy of ``value`` (one per instance)."""
    return lambda: type(value)(value)


def _normalise(tp: Any) -> Any:
    """``Sequence[X]`` -> ``tuple[X, ...]``; ``Optional`` parts kept."""
    origin = typing.get_origin(tp)
    if origin in (Sequence, list, typing.Sequence):
        (item,) = typing.get_args(tp) or (Any,)
        return tuple[item, ...]  # type: ignore[valid-type]  # built at run time from the annotation
    if _is_union(tp):
        return typing.Union[tuple(_normalise(a) for a in typing.get_args(tp))]  # noqa: UP007
    return tp


def _tuples_post_init(self) -> None:
    hints = typing.get_type_hints(type(self))
    for f in dataclasses.fields(self):
        value = getattr(self, f.name)
        if isinstance(value, list) and _tuple_item(hints[f.name]) is not None:
            object.__setattr__(self, f.name, tuple(value))


# --------------------------------------------------------------------------- JSON
def to_dict(config: Any) -> dict:
    """A JSON-able dict of a (nested) dataclass; tuples become lists."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def from_dict(cls: type, data: Mapping[str, Any]) -> Any:
    """Rebuild a (nested) dataclass from ``to_dict``'s output; lists given for tuple
    fields become tuples. Unknown keys are an error."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise TypeError(f"{cls.__name__} has no fields {sorted(unknown)}")
    kwargs = {}
    for key, value in data.items():
        tp = _strip_optional(hints[key])
        if _is_dataclass_type(tp) and isinstance(value, Mapping):
            value = from_dict(tp, value)
        elif isinstance(value, list) and _tuple_item(hints[key]) is not None:
            value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


def config_of(cls: type, model: Any) -> Any:
    """The ``cls`` (a ``model_config`` dataclass) describing a built model.

    Reads ``model.config``: a diffusers ``FrozenDict`` (keys starting with ``_`` are
    diffusers' bookkeeping) or a dataclass. Every field of ``cls`` must be present.
    """
    config = model.config
    data = (
        dataclasses.asdict(config)
        if dataclasses.is_dataclass(config) and not isinstance(config, type)
        else dict(config)
    )
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [n for n in names if n not in data]
    if missing:
        raise ValueError(f"{type(model).__name__}.config lacks {missing}")
    return from_dict(cls, {n: data[n] for n in names})


def differences(requested: Any, saved: Any, *, ignore: Sequence[str] = ()) -> dict[str, tuple[Any, Any]]:
    """``{field: (requested, saved)}`` where two configs of one dataclass differ; a
    requested None means "the model's default" and matches anything; ``ignore``: fields
    that are not part of the architecture (e.g. a local path)."""
    out = {}
    for f in dataclasses.fields(requested):
        a, b = getattr(requested, f.name), getattr(saved, f.name)
        if f.name not in ignore and a is not None and a != b:
            out[f.name] = (a, b)
    return out


# --------------------------------------------------------------------------- types
def _is_union(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType)


def _strip_optional(tp: Any) -> Any:
    if _is_union(tp):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _tuple_item(tp: Any) -> Any:
    """The item type of ``tuple[X, ...]`` (or ``Sequence[X]``), else None."""
    tp = _normalise(_strip_optional(tp))
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return args[0]
    return None


def _show(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (tuple, list)):
        return ",".join(_show(v) for v in value)
    if isinstance(value, dict):
        return json.dumps(value)
    if value == "":
        return '""'
    return str(value)


def _converter(tp: Any, flag: str) -> tuple[Callable[[str], Any], list | None, str | None]:
    """``(type function, choices, metavar)`` for a field type."""
    optional = _is_union(tp) and type(None) in typing.get_args(tp)
    base = _strip_optional(tp)
    choices = None
    convert: Callable[..., Any]
    if typing.get_origin(base) is typing.Literal:
        choices = list(typing.get_args(base))
        convert = type(choices[0])
        metavar = "{" + ",".join(map(str, choices)) + "}"
    elif _tuple_item(base) is not None:
        item = _tuple_item(base)

        def split(text: str, item=item) -> tuple:
            return tuple(item(v) for v in text.split(",") if v.strip())

        convert = split

        metavar = f"{item.__name__.upper()},..."
    elif base is dict:
        convert, metavar = json.loads, "JSON"
    elif base in (int, float, str):
        convert, metavar = base, base.__name__.upper()
    else:
        raise TypeError(f"{flag}: no command-line form for a field of type {tp!r}")
    if optional:
        inner = convert

        def or_none(text: str, inner=inner) -> Any:
            return None if text.lower() == "none" else inner(text)

        convert = or_none

    if choices is not None and optional:
        choices = [*choices, None]
    return convert, choices, metavar


class _Switch(argparse.Action):
    """``--x`` / ``--no-x`` (``--model.x`` / ``--model.no-x``); argparse's own
    BooleanOptionalAction words its help differently across Python versions."""

    def __init__(self, option_strings, dest, default=None, help=None):
        negated = [re.sub(r"^--((?:[\w-]+\.)*)", r"--\1no-", s) for s in option_strings]
        super().__init__([*option_strings, *negated], dest, nargs=0, default=default, help=help)
        self.negated = set(negated)

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, option_string not in self.negated)

    def format_usage(self) -> str:
        return " | ".join(self.option_strings)


class _Deprecated(argparse.Action):
    """An old spelling of a flag: stores into the new field and says so on stderr."""

    def __init__(self, option_strings, dest, replacement: str, **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.replacement = replacement

    def __call__(self, parser, namespace, values, option_string=None):
        print(
            f"{parser.prog}: note: {option_string} is deprecated (removed in the next release); use {self.replacement}",
            file=sys.stderr,
        )
        setattr(namespace, self.dest, values)


# --------------------------------------------------------------------------- argparse
def _flag(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _add_fields(parser: argparse.ArgumentParser, target, cls: type, prefix: str, specs: dict, values=None) -> None:
    """Add ``cls``'s fields to ``target`` (the parser or one of its groups); nested
    dataclasses get a group of their own on ``parser``. ``values``: an instance whose
    field values are the defaults (a nested field's ``default_factory`` may set other
    values than its class's defaults)."""
    hints = typing.get_type_hints(cls)
    docs = field_help(cls)
    nested = []
    for f in dataclasses.fields(cls):
        tp, dest = hints[f.name], prefix + f.name
        if values is not None:
            default = getattr(values, f.name)
        else:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc,operator]
        if _is_dataclass_type(tp):
            nested.append((f, tp, dest, default))
            continue
        text = docs.get(f.name, "").replace("%", "%%")
        help_text = f"{text} (default: {_show(default)})".strip()
        flag = _flag(dest)
        if _strip_optional(tp) is bool:
            target.add_argument(flag, dest=dest, action=_Switch, default=default, help=help_text)
            continue
        convert, choices, metavar = _converter(tp, flag)
        spec = dict(type=convert, choices=choices, metavar=metavar)
        specs[dest] = spec
        target.add_argument(flag, dest=dest, default=default, help=help_text, **spec)
    for f, tp, dest, default in nested:
        summary = docs.get(f.name) or (tp.__doc__ or "").split("\n")[0].replace("``", "")
        group = parser.add_argument_group(f"{_flag(dest)}.*", description=summary)
        _add_fields(parser, group, tp, dest + ".", specs, default)


def build_parser(
    cls: type, *, prog: str | None = None, description: str | None = None, aliases: Mapping[str, str] | None = None
) -> argparse.ArgumentParser:
    """An ``argparse`` parser with one flag per field of the dataclass ``cls`` (nested
    dataclasses: ``--name.field``); ``aliases`` maps an old flag (``"--resolution"``) to the
    field it now sets (``"model.resolution"``): accepted, with a note on stderr."""
    parser = argparse.ArgumentParser(prog=prog, description=description and description.replace("``", ""))
    specs: dict[str, dict] = {}
    _add_fields(parser, parser, cls, "", specs)
    if aliases:
        group = parser.add_argument_group("deprecated spellings (removed in the next release)")
        for old, dest in aliases.items():
            if dest not in specs:
                raise ValueError(f"alias {old}: no field {dest!r} that takes a value")
            group.add_argument(
                old,
                dest=dest,
                action=_Deprecated,
                replacement=_flag(dest),
                default=argparse.SUPPRESS,
                help=f"same as {_flag(dest)}",
                **specs[dest],
            )
    return parser


def _build(cls: type, values: dict[str, Any], prefix: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        dest = prefix + f.name
        if _is_dataclass_type(hints[f.name]):
            kwargs[f.name] = _build(hints[f.name], values, dest + ".")
        else:
            kwargs[f.name] = values[dest]
    return cls(**kwargs)


def parse(
    cls: type,
    argv: Sequence[str] | None = None,
    *,
    prog: str | None = None,
    description: str | None = None,
    aliases: Mapping[str, str] | None = None,
) -> Any:
    """Parse ``argv`` (default: ``sys.argv[1:]``) into an instance of the dataclass ``cls``
    (``build_parser``); ``--help`` prints every field with its help and default."""
    parser = build_parser(cls, prog=prog, description=description, aliases=aliases)
    return _build(cls, vars(parser.parse_args(argv)))
