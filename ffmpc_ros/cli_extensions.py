"""Extension points of the ``ffmpc`` command line, as ros2cli's (``ros2cli.command`` and the
``ros2<command>.verb`` groups): a package one layer up adds commands without ``ffmpc_ros``
importing it.

A package declares its commands as Python entry points (``[project.entry-points]`` of
pyproject.toml; the entry point's name is the command's name, its value a
:class:`CommandExtension` subclass or instance):

* group :data:`COMMAND_GROUP` (``ffmpc.command``): top-level commands, ``ffmpc NAME ...``
  (``study``, ``tune``: ``studies/cli.py``);
* group :data:`BENCH_GROUP` (``ffmpc.bench``): verbs of ``ffmpc bench``, ``ffmpc bench NAME ...``
  (``impact``: ``studies/cli.py``).

:func:`add_extension_parsers` reads a group with :mod:`importlib.metadata` and adds one
sub-parser per entry point; the extension fills it (:meth:`CommandExtension.add_arguments`) and
runs it (:meth:`CommandExtension.main`). Entry points are read from the installed metadata:
after editing them, reinstall (``make install``). An extension that fails to load is skipped
with one warning line on stderr; the other commands still work.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable
from importlib import metadata
from typing import Any

#: Entry-point group of the top-level commands (``ffmpc NAME``).
COMMAND_GROUP = "ffmpc.command"
#: Entry-point group of the ``ffmpc bench`` verbs (``ffmpc bench NAME``).
BENCH_GROUP = "ffmpc.bench"


class CommandExtension:
    """A command (or verb) added to ``ffmpc`` by another package.

    Attributes:
        help: one line for the parent's ``--help`` list.
        description: the command's own ``--help`` text (default: ``help``).
        verb_dest: the ``dest`` of the command's own sub-commands, if it has any (``ffmpc study``:
            ``study``), so that an error names the whole command (``ffmpc study impact: error``).
    """

    help: str = ""
    description: str | None = None
    verb_dest: str | None = None

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Add the command's flags (and sub-commands) to ``parser``; import nothing heavy."""

    def main(self, args: argparse.Namespace) -> int:
        """Run the command; the exit status (0 ok). Raise FfmpcError/OSError on bad input."""
        raise NotImplementedError


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def load_extensions(
    group: str,
    entry_points: Iterable[metadata.EntryPoint] | None = None,
    warn: Callable[[str], None] | None = None,
) -> dict[str, CommandExtension]:
    """The extensions of entry-point ``group`` (default: the installed ones), by name, sorted.

    An entry point that fails to import, is not a :class:`CommandExtension` or repeats a name
    is skipped with one line to ``warn`` (default: stderr)."""
    if warn is None:

        def warn(text: str) -> None:
            print(f"ffmpc: warning: {text}", file=sys.stderr)

    found = metadata.entry_points(group=group) if entry_points is None else entry_points
    extensions: dict[str, CommandExtension] = {}
    for ep in sorted(found, key=lambda e: e.name):
        where = f"{group} entry point {ep.name!r} ({ep.value})"
        if ep.name in extensions:
            warn(f"{where}: the name is taken by another entry point; skipped")
            continue
        try:
            obj: Any = ep.load()
            extension = obj() if isinstance(obj, type) else obj
        except Exception as exc:  # a broken extension must not take the other commands down
            warn(f"{where} failed to load: {type(exc).__name__}: {_one_line(exc)}")
            continue
        if not isinstance(extension, CommandExtension):
            warn(f"{where} is not a CommandExtension; skipped")
            continue
        extensions[ep.name] = extension
    return extensions


def add_extension_parsers(
    subparsers: Any,
    group: str,
    reserved: Iterable[str] = (),
    entry_points: Iterable[metadata.EntryPoint] | None = None,
    warn: Callable[[str], None] | None = None,
) -> list[str]:
    """Add a sub-parser to ``subparsers`` (an ``add_subparsers()`` action) for every extension
    of ``group`` whose name is not ``reserved`` (a built-in command: refused with a warning);
    the names added."""
    reserved_names = set(reserved)
    extensions = load_extensions(group, entry_points, warn)
    added = []
    for name, extension in extensions.items():
        if name in reserved_names:
            message = f"{group} entry point {name!r} shadows a built-in command; skipped"
            if warn is None:
                print(f"ffmpc: warning: {message}", file=sys.stderr)
            else:
                warn(message)
            continue
        parser = subparsers.add_parser(
            name, help=extension.help, description=extension.description or extension.help
        )
        extension.add_arguments(parser)
        parser.set_defaults(func=extension.main, verb_dest_=extension.verb_dest)
        added.append(name)
    return added
