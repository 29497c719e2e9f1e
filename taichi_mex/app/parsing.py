"""Argument parsing shared by the sub-commands: errors as UserInputError, and the flags that
the option declarations (``opt(flag=...)``) generate for a scene's run description."""

from __future__ import annotations

import argparse
import math
import typing
from dataclasses import MISSING

from taichi_mex.errors import UserInputError
from taichi_mex.spec import spec_fields


class Parser(argparse.ArgumentParser):
    """argparse that reports errors through UserInputError (one paragraph, exit 2)."""

    def error(self, message):
        raise UserInputError(f"{message}. Run '{self.prog} --help' for the options.")


def _finite(kind):
    def convert(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a {'whole ' if kind is int else ''}"
                                             "number") from None
        if isinstance(value, float) and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"'{text}' is not a finite number")
        return value
    convert.__name__ = kind.__name__
    return convert


def _parsing(parse):
    def convert(text: str):
        try:
            return parse(text)
        except UserInputError as exc:
            raise argparse.ArgumentTypeError(str(exc).rstrip(".")) from None
    convert.__name__ = getattr(parse, "__name__", "value")
    return convert


def _value_type(hint):
    args = [a for a in typing.get_args(hint) if a is not type(None)] or [hint]
    if str in args:
        return str
    for kind in (float, int):
        if kind in args:
            return _finite(kind)
    return str


_GROUPS = (("scene.", "{scene} options"), ("run.thermal.", "heat (off unless --thermal or a heat "
           "option is given)"), ("run.", "discretisation and solver"), ("material.", "material"))


def add_spec_flags(parser: argparse.ArgumentParser, scene: str) -> set[str]:
    """Add every declared flag of a ``scene`` run; returns the dests (dotted option paths).
    Flags default to 'not given', so that only what the user typed changes the description."""
    groups = {prefix: parser.add_argument_group(title.format(scene=scene)) for prefix, title in _GROUPS}
    dests = set()
    for path, f in spec_fields(scene):
        flags = f.metadata.get("flag")
        if not flags:
            continue
        group = next(groups[p] for p, _ in _GROUPS if path.startswith(p))
        # argparse formats help with %: option help is prose ("+6 % at ...")
        help_text = (f.metadata.get("flag_help") or f.metadata["help"]).replace("%", "%%")
        const = f.metadata.get("const", MISSING)
        if const is not MISSING:
            group.add_argument(*flags, dest=path, action="store_const", const=const,
                               default=argparse.SUPPRESS, help=help_text)
            if f.metadata.get("flag_not"):
                group.add_argument(f.metadata["flag_not"], dest=path, action="store_const",
                                   const=not const, default=argparse.SUPPRESS,
                                   help=f.metadata["help"].replace("%", "%%"))
        else:
            parse = f.metadata.get("parse")
            hint = typing.get_type_hints(_owner(path, scene))[f.name]
            group.add_argument(*flags, dest=path, default=argparse.SUPPRESS,
                               action="append" if f.metadata.get("repeat") else "store",
                               type=_parsing(parse) if parse else _value_type(hint),
                               metavar=flags[0].lstrip("-").upper().replace("-", "_"),
                               help=help_text)
        dests.add(path)
    return dests


def _owner(path: str, scene: str):
    """The dataclass type that declares the option at a dotted path."""
    from dataclasses import MISSING, fields

    from taichi_mex.options import Material, RunOptions
    from taichi_mex.spec import scene_entry

    root, *parts = path.split(".")
    cls = {"scene": scene_entry(scene).options, "run": RunOptions, "material": Material}[root]
    for part in parts[:-1]:
        f = next(f for f in fields(cls) if f.name == part)
        cls = type(f.default_factory() if f.default_factory is not MISSING else f.default)
    return cls


def spec_changes(args: argparse.Namespace, dests: set[str]) -> dict:
    """The options the user gave on the command line, as dotted paths."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in vars(args).items() if k in dests}
