"""Each paper equation mapped to the code that implements it, read from the docstrings.

The rule the code follows (BRIEF/DESIGN: "each paper equation in one named, documented
function"): a docstring that implements or uses an equation names it, ``eq 16``, ``eq 3–8``,
``eq 10/15``, ``Eq 25.3``. :func:`equation_map` scans every docstring of ``ffmpc_core``
(modules, classes, functions, methods) and assigns each reference to its paper by package:
``ffmpc_core.impact`` is Dehio & Kheddar 2020, the rest Kleff et al. 2024.

:data:`PAPERS` lists every numbered equation of both papers (``../shared/papers/*.md``;
``tests/test_docs_reference.py`` checks the list against those files when they are present).
An equation no docstring names must be in :data:`NOT_IMPLEMENTED` with the reason, or the
manual's build fails (:func:`unmapped`).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Paper:
    """A paper of the spec: key, citation, equation numbers, and the package implementing it."""

    key: str
    citation: str
    file: str
    equations: tuple[int, ...]


PAPERS = (
    Paper(
        "kleff2024",
        "Kleff et al. 2024, force-feedback MPC with soft contacts",
        "force-feedback-mpc-soft-contact.md",
        tuple(range(1, 38)),
    ),
    Paper(
        "dehio2020",
        "Dehio & Kheddar 2020, safe maximal impacts on soft contacts",
        "safe-impacts-soft-contacts-learned-deformations.md",
        tuple(range(1, 22)),
    ),
)

#: Equations of the papers that no function implements, and why. The build fails for an
#: equation that is neither mapped nor listed here.
NOT_IMPLEMENTED: dict[tuple[str, int], str] = {
    ("kleff2024", 1): "the generic OCP; every formulation is an instance of it "
    "(crocoddyl's ShootingProblem)",
    ("kleff2024", 2): "the NLP transcription of eq 1: crocoddyl's ShootingProblem, solved by "
    "mim_solvers' SQP",
    ("kleff2024", 36): "an analysis of the pure-damper case in the paper's discussion, not an "
    "algorithm",
    ("kleff2024", 37): "the torque estimate of the paper's hardware (RNEA minus the external "
    "torque); the simulated plant measures the applied torque of eq 31",
}

_REF = re.compile(
    r"(?<![\w.])[Ee]qs?\.?\s+(\d+)(?:\.\d+)?[a-z]?(?:\s*[–-]\s*(\d+)(?:\.\d+)?)?"
    r"((?:\s*(?:,|/|and)\s*\d+(?:\.\d+)?[a-z]?(?:\s*[–-]\s*\d+)?(?![\d/·]|\s*ms\b))*)"
)
_ITEM = re.compile(r"(\d+)(?:\.\d+)?[a-z]?(?:\s*[–-]\s*(\d+))?")


def equation_numbers(text: str) -> set[int]:
    """The equation numbers ``text`` names: ``eq 3–8`` → 3..8, ``eq 10/15`` → 10, 15,
    ``eq 1, 2, 9`` → 1, 2, 9, ``eq 25.3`` → 25. A number followed by a unit is not an equation
    (``eq 28, 1/(N·m)²``)."""
    out: set[int] = set()
    for match in _REF.finditer(text):
        first, last, rest = match.groups()
        out.update(range(int(first), int(last or first) + 1))
        for item in _ITEM.finditer(rest or ""):
            a, b = item.groups()
            out.update(range(int(a), int(b or a) + 1))
    return out


@dataclass(frozen=True)
class Implementation:
    """An object of ``ffmpc_core`` whose docstring names equations of a paper."""

    paper: str
    qualname: str  # dotted: module.Class.method
    kind: str  # module, class, function, method
    summary: str
    equations: tuple[int, ...]


def _summary(doc: str) -> str:
    first = doc.strip().split("\n\n")[0]
    return " ".join(first.split())


def _paper_of(module: str) -> str:
    return "dehio2020" if module.startswith("ffmpc_core.impact") else "kleff2024"


def _documented_objects(package: str = "ffmpc_core") -> list[tuple[str, str, object]]:
    """(qualname, kind, object) of the package's public modules, classes, functions and
    methods defined in them."""
    root = importlib.import_module(package)
    names = [package] + [
        m.name
        for m in pkgutil.walk_packages(root.__path__, package + ".")
        if not any(part.startswith("_") for part in m.name.split("."))
    ]
    out: list[tuple[str, str, object]] = []
    for name in names:
        module = importlib.import_module(name)
        out.append((name, "module", module))
        for attr, obj in vars(module).items():
            if attr.startswith("_") or getattr(obj, "__module__", None) != name:
                continue
            if inspect.isclass(obj):
                out.append((f"{name}.{attr}", "class", obj))
                for mname, member in vars(obj).items():
                    if mname.startswith("_") and mname != "__init__":
                        continue
                    func = getattr(member, "__func__", member)
                    if isinstance(member, property):
                        func = member.fget
                    if inspect.isfunction(func):
                        out.append((f"{name}.{attr}.{mname}", "method", func))
            elif inspect.isfunction(obj):
                out.append((f"{name}.{attr}", "function", obj))
    return out


def equation_map(package: str = "ffmpc_core") -> list[Implementation]:
    """Every object of ``package`` whose own docstring names an equation, with the numbers."""
    out = []
    for qualname, kind, obj in _documented_objects(package):
        doc = obj.__doc__ if kind != "module" else obj.__doc__  # own docstring, not inherited
        if not doc:
            continue
        numbers = equation_numbers(doc)
        if numbers:
            module = qualname if kind == "module" else obj.__module__
            out.append(
                Implementation(
                    _paper_of(module), qualname, kind, _summary(doc), tuple(sorted(numbers))
                )
            )
    return out


def unmapped(implementations: list[Implementation]) -> list[tuple[str, int]]:
    """(paper, equation) of every equation no docstring names and :data:`NOT_IMPLEMENTED`
    does not explain."""
    found = {(i.paper, n) for i in implementations for n in i.equations}
    return [
        (p.key, n)
        for p in PAPERS
        for n in p.equations
        if (p.key, n) not in found and (p.key, n) not in NOT_IMPLEMENTED
    ]


def stale_exemptions(implementations: list[Implementation]) -> list[tuple[str, int]]:
    """Entries of :data:`NOT_IMPLEMENTED` that a docstring now names (the table must not say an
    implemented equation is not implemented)."""
    found = {(i.paper, n) for i in implementations for n in i.equations}
    return sorted(k for k in NOT_IMPLEMENTED if k in found)
