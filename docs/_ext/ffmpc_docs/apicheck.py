"""The rule ``make docs`` enforces on the Python API of ``ffmpc_core``: every public module,
class, function, method and property has a docstring of its own (a method that overrides a
documented method of a base class, crocoddyl's ``calc`` for instance, may inherit it).

Public: a name without a leading underscore, defined in the module that holds it (not
imported), in a module whose dotted path has no part with a leading underscore
(``ffmpc_core._native``, the compiled module, is documented through ``ffmpc_core.native``).
A dataclass without a docstring gets one from Python (``Name(field: type, ...)``): that does not
count as documented.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from dataclasses import dataclass, is_dataclass


@dataclass(frozen=True)
class Missing:
    """A public object without a docstring: dotted name, kind, source file and line."""

    qualname: str
    kind: str
    file: str
    line: int


def public_modules(package: str) -> list[str]:
    """The dotted names of ``package`` and its public submodules, sorted."""
    root = importlib.import_module(package)
    names = [package] + [
        m.name
        for m in pkgutil.walk_packages(root.__path__, package + ".")
        if not any(part.startswith("_") for part in m.name.split("."))
    ]
    return sorted(names)


def _own_doc(obj: object) -> str:
    doc = getattr(obj, "__doc__", None) or ""
    if inspect.isclass(obj) and is_dataclass(obj) and doc.startswith(obj.__name__ + "("):
        return ""  # the dataclass decorator's signature text
    return doc.strip()


def _where(obj: object) -> tuple[str, int]:
    try:
        target = inspect.unwrap(obj)  # type: ignore[arg-type]
        return inspect.getsourcefile(target) or "", inspect.getsourcelines(target)[1]
    except (TypeError, OSError):
        return "", 0


def _inherited_doc(cls: type, name: str) -> bool:
    for base in cls.__mro__[1:]:
        member = getattr(base, name, None)
        if member is not None and (getattr(member, "__doc__", None) or "").strip():
            return True
    return False


def undocumented(package: str = "ffmpc_core") -> list[Missing]:
    """Every public object of ``package`` without a docstring."""
    missing: list[Missing] = []

    def report(qualname: str, kind: str, obj: object) -> None:
        file, line = _where(obj)
        missing.append(Missing(qualname, kind, file, line))

    for name in public_modules(package):
        module = importlib.import_module(name)
        if not _own_doc(module):
            report(name, "module", module)
        for attr, obj in vars(module).items():
            if attr.startswith("_") or getattr(obj, "__module__", None) != name:
                continue
            if inspect.isclass(obj):
                if not _own_doc(obj):
                    report(f"{name}.{attr}", "class", obj)
                _check_members(name, attr, obj, report)
            elif inspect.isfunction(obj) and not _own_doc(obj):
                report(f"{name}.{attr}", "function", obj)
    return missing


def _check_members(module: str, cls_name: str, cls: type, report) -> None:  # noqa: ANN001
    for mname, member in vars(cls).items():
        if mname.startswith("_"):
            continue
        if isinstance(member, property):
            func = member.fget
            kind = "property"
        else:
            func = getattr(member, "__func__", member)
            kind = "method"
        if not inspect.isfunction(func):
            continue
        if not _own_doc(func) and not _inherited_doc(cls, mname):
            report(f"{module}.{cls_name}.{mname}", kind, func)
