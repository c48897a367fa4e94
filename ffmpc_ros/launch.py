"""``ffmpc launch FILE``: run a ROS 2 YAML launch file without ``launch_ros``.

``launch_ros`` has no wheel on the package index, so on a machine without a full ROS install
``ros2 launch`` is missing. This runs the same files (``share/ffmpc_ros/launch/*.launch.yaml``),
a tested subset of the YAML launch syntax (``launch_yaml``), one process per node:

* ``arg``: ``name``, ``default``, ``description``; set on the command line as ``name:=value``
  (as ``ros2 launch``); an argument without a default must be given.
* ``node``: ``pkg``, ``exec``, ``name``, ``namespace``, ``output`` (``screen``: each line
  prefixed ``[name]``; ``log``: into the log directory only), ``param`` (a list of
  ``{from: FILE}`` parameter files and ``{name: N, value: V}`` entries, in order),
  ``remap`` (``{from: A, to: B}``), ``ros_args`` (a string) and ``on_exit: shutdown``.
* substitutions in any string: ``$(var NAME)``, ``$(env NAME)``, ``$(env NAME DEFAULT)`` and
  ``$(find-pkg-share PKG)``, ``$(find-pkg-prefix PKG)`` (through ``ament_index_python``, as
  ``ros2 launch`` resolves them).

Run with the real ``ros2 launch`` too (launch 3.4.3, launch_ros 0.26.6, the Jazzy releases,
built from source here: docs/explanation/design.md, "More measured facts"), the same files give the
same
command lines and parameters (``tests/test_launch.py`` compares them when a launch_ros is found)
and the same metrics. As there, parameter files are passed unchanged: a namespaced node
(``polishing.launch.yaml namespace:=/arm1``) gets ``-r __ns:=/arm1`` and reads the sections keyed
``/**/plant`` (the shipped scenario files) or ``/arm1/plant``, never a bare ``plant:`` (rcl reads it
as ``/plant``): such a section is reported in one warning line per node. A ``{name, value}``
parameter is a file keyed by the node's fully qualified name, as launch_ros writes it, so it
overrides the files before it; a parameter value with a substitution is read as YAML and must
be a scalar or a list of one type, as launch_ros requires.

Anything else (another tag, another key) is refused with its name: an option that would be
silently ignored is an error here. Executables resolve as ``ros2 run`` does
(``<prefix of PKG>/lib/PKG/EXE``). Every node dies with the launcher (PR_SET_PDEATHSIG). As with
``ros2 launch``, a node with ``on_exit: shutdown`` ends the launch when it exits, another node's
exit does not, and the launch ends when no node runs; Ctrl-C (SIGINT) or SIGTERM stops it. Nodes
are stopped as launch stops them: SIGINT, SIGTERM after :data:`SIGTERM_TIMEOUT` s, SIGKILL after
:data:`SIGKILL_TIMEOUT` s more. One difference: ``ros2 launch`` exits 0 whatever its nodes
returned; this returns the exit code of the node whose exit ended the launch, or else the first
failure (124 past ``--timeout``, 128+N on signal N).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import re
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import yaml

from ffmpc_core.errors import FfmpcError

#: Wall time a node gets to exit after SIGINT before SIGTERM, then after SIGTERM before SIGKILL,
#: s (launch's ``sigterm_timeout`` and ``sigkill_timeout`` defaults).
SIGTERM_TIMEOUT = 5.0
SIGKILL_TIMEOUT = 5.0
_SUBSTITUTION = re.compile(r"\$\(([a-z-]+)((?:\s+[^)\s]+)*)\s*\)")
_ARG_KEYS = {"name", "default", "description"}
_NODE_KEYS = {"pkg", "exec", "name", "namespace", "output", "param", "remap", "ros_args", "on_exit"}


class LaunchError(FfmpcError):
    """A launch file this launcher cannot run (unknown tag, key or argument, bad substitution)."""


@dataclass(frozen=True)
class LaunchNode:
    """One ``node`` entry, substitutions resolved."""

    package: str
    executable: str
    name: str | None = None
    namespace: str | None = None
    output: str = "log"
    parameters: tuple[tuple[str, Any], ...] = ()  # ("file", path) or (name, value), in order
    remaps: tuple[tuple[str, str], ...] = ()
    ros_args: tuple[str, ...] = ()
    shutdown_on_exit: bool = False

    @property
    def label(self) -> str:
        return self.name or self.executable


@dataclass(frozen=True)
class LaunchDescription:
    """What a launch file runs: its arguments' values and its nodes."""

    arguments: dict[str, str] = field(default_factory=dict)
    nodes: tuple[LaunchNode, ...] = ()


def package_prefix(package: str) -> str:
    """The install prefix of ``package``: the ament index of ``AMENT_PREFIX_PATH`` (as
    ``ros2 run`` resolves it), then this environment's prefix (a venv without a sourced ROS)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        return get_package_prefix(package)
    except (PackageNotFoundError, OSError, LookupError):
        marker = Path(sys.prefix, "share", "ament_index", "resource_index", "packages", package)
        if marker.is_file():
            return sys.prefix
        raise LaunchError(
            f"package {package!r} not found (AMENT_PREFIX_PATH, {sys.prefix})"
        ) from None


def substitute(text: str, variables: Mapping[str, str]) -> str:
    """``text`` with its ``$(...)`` substitutions resolved (module docstring)."""

    def one(match: re.Match[str]) -> str:
        kind, args = match.group(1), match.group(2).split()
        if kind == "var" and len(args) == 1:
            if args[0] not in variables:
                raise LaunchError(f"$(var {args[0]}): no such launch argument")
            return variables[args[0]]
        if kind == "env" and len(args) in (1, 2):
            value = os.environ.get(args[0], args[1] if len(args) == 2 else None)
            if value is None:
                raise LaunchError(f"$(env {args[0]}): not set and no default")
            return value
        if kind == "find-pkg-prefix" and len(args) == 1:
            return package_prefix(args[0])
        if kind == "find-pkg-share" and len(args) == 1:
            return os.path.join(package_prefix(args[0]), "share", args[0])
        raise LaunchError(f"unsupported substitution $({match.group(1)}{match.group(2)})")

    return _SUBSTITUTION.sub(one, text)


_SCALARS = (bool, int, float, str)


def _parameter_value(name: str, value: Any, variables: Mapping[str, str]) -> Any:
    """A parameter's value as launch_ros evaluates it: a string with a substitution is read as
    YAML after substituting (``value: $(var duration)`` gives a float; a plain string stays a
    string), in a list item by item; the result must be a scalar or a non-empty list of one
    scalar type (LaunchError otherwise, as launch_ros refuses it)."""

    def one(item: Any) -> Any:
        if not isinstance(item, str):
            return item
        out = substitute(item, variables)
        if out == item and not _SUBSTITUTION.search(item):
            return item
        try:
            return yaml.safe_load(out) if out else ""
        except yaml.YAMLError:
            raise LaunchError(f"parameter {name}: {out!r} is not a YAML value") from None

    out = [one(v) for v in value] if isinstance(value, list) else one(value)
    if isinstance(out, list):
        if not out or type(out[0]) not in _SCALARS or any(type(v) is not type(out[0]) for v in out):
            raise LaunchError(f"parameter {name}: {out!r} is not a non-empty list of one type")
    elif type(out) not in _SCALARS:
        raise LaunchError(f"parameter {name}: {out!r} is not a bool, int, float, string or list")
    return out


def _entries(doc: Any, path: str) -> list[tuple[str, dict]]:
    if not isinstance(doc, dict) or set(doc) != {"launch"} or not isinstance(doc["launch"], list):
        raise LaunchError(f"{path}: a YAML launch file is one mapping 'launch:' with a list")
    out = []
    for item in doc["launch"]:
        if not isinstance(item, dict) or len(item) != 1:
            raise LaunchError(f"{path}: each launch entry is one tag, got {item!r}")
        ((tag, body),) = item.items()
        if not isinstance(body, dict):
            raise LaunchError(f"{path}: '{tag}' needs a mapping, got {body!r}")
        out.append((str(tag), body))
    return out


def _check_keys(tag: str, body: dict, allowed: set[str]) -> None:
    unknown = sorted(set(body) - allowed)
    if unknown:
        raise LaunchError(f"'{tag}': unsupported key(s) {unknown} (supported: {sorted(allowed)})")


def _node(body: dict, variables: Mapping[str, str]) -> LaunchNode:
    _check_keys("node", body, _NODE_KEYS)
    for key in ("pkg", "exec"):
        if key not in body:
            raise LaunchError(f"'node' needs '{key}'")
    text = {
        k: substitute(str(body[k]), variables)
        for k in ("pkg", "exec", "name", "namespace")
        if k in body
    }
    output = str(body.get("output", "log"))
    if output not in ("screen", "log"):
        raise LaunchError(f"'node' output {output!r}: screen or log")
    on_exit = body.get("on_exit")
    if on_exit not in (None, "shutdown"):
        raise LaunchError(f"'node' on_exit {on_exit!r}: only 'shutdown' is supported")
    parameters: list[tuple[str, Any]] = []
    for entry in body.get("param") or []:
        if isinstance(entry, dict) and set(entry) == {"from"}:
            parameters.append(("file", substitute(str(entry["from"]), variables)))
        elif isinstance(entry, dict) and set(entry) == {"name", "value"}:
            name = substitute(str(entry["name"]), variables)  # qos_overrides.$(var namespace)/…
            parameters.append((name, _parameter_value(name, entry["value"], variables)))
        else:
            raise LaunchError(f"'param' entry {entry!r}: {{from: FILE}} or {{name: N, value: V}}")
    remaps = []
    for entry in body.get("remap") or []:
        if not isinstance(entry, dict) or set(entry) != {"from", "to"}:
            raise LaunchError(f"'remap' entry {entry!r}: {{from: A, to: B}}")
        remaps.append(
            (substitute(str(entry["from"]), variables), substitute(str(entry["to"]), variables))
        )
    ros_args = substitute(str(body.get("ros_args", "")), variables).split()
    return LaunchNode(
        package=text["pkg"],
        executable=text["exec"],
        name=text.get("name"),
        namespace=text.get("namespace"),
        output=output,
        parameters=tuple(parameters),
        remaps=tuple(remaps),
        ros_args=tuple(ros_args),
        shutdown_on_exit=on_exit == "shutdown",
    )


def load_launch_file(
    path: str | os.PathLike, arguments: Mapping[str, str] | None = None
) -> LaunchDescription:
    """Parse a YAML launch file with ``arguments`` (``name → value``) for its ``arg`` entries."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as fh:
            doc = yaml.safe_load(fh)
    except OSError as exc:
        raise LaunchError(f"cannot read {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise LaunchError(f"{path}: not YAML: {exc}") from None
    given = dict(arguments or {})
    variables: dict[str, str] = {}
    nodes = []
    declared = set()
    for tag, body in _entries(doc, path):
        if tag == "arg":
            _check_keys("arg", body, _ARG_KEYS)
            name = str(body.get("name", ""))
            if not name:
                raise LaunchError("'arg' needs a name")
            declared.add(name)
            if name in given:
                variables[name] = given[name]
            elif "default" in body:
                variables[name] = substitute(str(body["default"]), variables)
            else:
                raise LaunchError(f"launch argument '{name}' has no default: give {name}:=VALUE")
        elif tag == "node":
            nodes.append(_node(body, variables))
        else:
            raise LaunchError(f"unsupported launch tag '{tag}' (supported: arg, node)")
    unknown = sorted(set(given) - declared)
    if unknown:
        raise LaunchError(f"unknown launch argument(s) {unknown} (declared: {sorted(declared)})")
    return LaunchDescription(arguments=variables, nodes=tuple(nodes))


def node_fqn(node: LaunchNode) -> str:
    """The node's fully qualified name as a parameter file keys it (``/**`` without a name)."""
    if not node.name:
        return "/**"
    namespace = (node.namespace or "").strip("/")
    return "/" + "/".join(p for p in (namespace, node.name) if p)


def node_command(node: LaunchNode, params_dir: str | os.PathLike) -> list[str]:
    """The command line of a node, as ``ros2 run PKG EXE --ros-args ...`` would run it.

    Parameters keep their order as launch_ros keeps it: each run of ``{name, value}`` entries
    becomes a parameter file of its own (keyed by the node's name, written into
    ``params_dir``), passed with ``--params-file`` between the ``from`` files, so a later entry
    overrides an earlier one (a ``-p`` would lose against a file's node section)."""
    from ffmpc_ros.graph_nodes import nested_parameters

    exe = os.path.join(package_prefix(node.package), "lib", node.package, node.executable)
    if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        raise LaunchError(f"no executable {node.executable!r} in package {node.package!r} ({exe})")
    args = ["--ros-args"]
    if node.name:
        args += ["-r", f"__node:={node.name}"]
    if node.namespace:
        args += ["-r", f"__ns:={node.namespace}"]
    groups: list[tuple[str, Any]] = []  # ("file", path) or ("values", {name: value})
    for name, value in node.parameters:
        if name == "file":
            groups.append(("file", value))
        elif groups and groups[-1][0] == "values":
            groups[-1][1][name] = value
        else:
            groups.append(("values", {name: value}))
    for i, (kind, item) in enumerate(groups):
        if kind == "values":
            path = os.path.join(params_dir, f"{node.label}_{i}.yaml")
            with open(path, "w", encoding="utf-8") as fh:
                tree = {node_fqn(node): {"ros__parameters": nested_parameters(item)}}
                yaml.safe_dump(tree, fh, sort_keys=False)
            item = path
        args += ["--params-file", item]
    for source, target in node.remaps:
        args += ["-r", f"{source}:={target}"]
    return [exe, *args, *node.ros_args]


def unreached_sections(node: LaunchNode) -> list[str]:
    """The sections of the node's parameter files keyed by its bare name (``plant:``, which rcl
    reads as ``/plant``) when the node runs under a namespace: they do not reach it, with
    ``ros2 launch`` as here (files are passed unchanged); ``/**/plant:`` would."""
    fqn = node_fqn(node)
    if not node.name or fqn == f"/{node.name}":
        return []
    out = []
    for kind, path in node.parameters:
        if kind != "file":
            continue
        try:
            with open(path, encoding="utf-8") as fh:
                doc = yaml.safe_load(fh)
        except (OSError, yaml.YAMLError):
            continue  # the node reports an unreadable file itself
        if isinstance(doc, dict):
            out += [f"{path}: {key}" for key in doc if key in (node.name, f"/{node.name}")]
    return out


def check_launch(description: LaunchDescription) -> None:
    """Every parameter of every ffmpc node of the launch checked as the node would check it,
    before any process starts (ConfigError, one line): a parameter file made of scenario
    sections (``/**``, ``/**/mpc``, ...) is a scenario and must load as ``ffmpc run`` loads one
    (complete or based on another, its values by the schema); the values of the other files
    that reach the node, and each ``{name, value}`` entry, by
    :func:`ffmpc_ros.params.check_node_parameter` (an entry the node does not declare would do
    nothing: refused). Nodes of other packages are left to themselves."""
    from ffmpc_ros.params import NODE_SPECS, check_node_parameter, declares

    for node in description.nodes:
        if node.package != "ffmpc_ros" or node.executable not in NODE_SPECS:
            continue
        spec = node.executable
        for name, item in node.parameters:
            if name == "file":
                values = _file_values(item, node)
                given = {k: v for k, v in values.items() if declares(spec, k)}
            else:
                given = {name: _as_node_reads(item)}
            for key, value in given.items():
                try:
                    check_node_parameter(spec, key, value)
                except FfmpcError as exc:
                    raise LaunchError(f"node {node.label}: {exc}") from None


def _as_node_reads(value: Any) -> Any:
    """A ``{name, value}`` entry's value as the node reads it: launch_ros (and
    :func:`node_command`) write it to a parameter file, which rcl parses (``"1e4"`` becomes
    10000.0)."""
    from ffmpc_core.values import load_yaml

    return load_yaml(yaml.safe_dump({"v": value}))["v"]


def _file_values(path: str, node: LaunchNode) -> dict[str, Any]:
    """The values a parameter file gives ``node`` (sections ``/**``, ``/**/NAME``, its fully
    qualified name, a bare ``NAME`` at the root), read by rcl's rules; a scenario file is
    loaded as ``ffmpc run`` loads it first (LaunchError with the reason)."""
    from ffmpc_core.scenario import ANY_NAMESPACE, SECTIONS, WILDCARD, flatten, load_scenario
    from ffmpc_core.values import load_yaml

    try:
        with open(path, encoding="utf-8") as fh:
            doc = load_yaml(fh)
    except OSError as exc:
        raise LaunchError(f"node {node.label}: cannot read {path}: {exc.strerror}") from None
    except (yaml.YAMLError, FfmpcError) as exc:
        raise LaunchError(f"node {node.label}: {path}: not a parameter file ({exc})") from None
    if not isinstance(doc, dict):
        raise LaunchError(f"node {node.label}: {path}: not a parameter file")
    scenario_keys = {WILDCARD, *SECTIONS, *(ANY_NAMESPACE + s for s in SECTIONS)}
    if set(doc) <= scenario_keys:
        try:
            load_scenario(path)
        except FfmpcError as exc:
            raise LaunchError(f"node {node.label}: {exc}") from None
    fqn = node_fqn(node)
    reach = {WILDCARD, fqn, f"{ANY_NAMESPACE}{node.name}"}
    if fqn == f"/{node.name}":
        reach.add(str(node.name))
    out: dict[str, Any] = {}
    for key, body in doc.items():
        if str(key) in reach and isinstance(body, dict):
            out.update(flatten(body.get("ros__parameters") or {}))
    return out


def _die_with_parent() -> None:
    """In a child before exec: SIGINT when the launcher dies (no orphan node)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGINT, 0, 0, 0)  # PR_SET_PDEATHSIG


def prepare_launch(
    description: LaunchDescription, log_dir: str | os.PathLike, out: IO[str]
) -> list[tuple[LaunchNode, list[str]]]:
    """(node, command line) of every node, before any starts (:func:`node_command`: its
    parameter files written into ``log_dir``); one warning line on ``out`` per parameter
    section that does not reach its node (:func:`unreached_sections`); LaunchError for a
    missing executable or two nodes of one name."""
    Path(log_dir).mkdir(parents=True, exist_ok=True)
    commands = [(node, node_command(node, log_dir)) for node in description.nodes]
    for node in description.nodes:
        for section in unreached_sections(node):
            print(
                f"[launch] WARNING {node.label}: section {section} does not reach "
                f"{node_fqn(node)} (key it /**/{node.name})",
                file=out,
                flush=True,
            )
    labels = [node.label for node in description.nodes]
    if len(set(labels)) != len(labels):
        raise LaunchError(f"two nodes share a name: {labels}")
    return commands


class LaunchSession:
    """The processes of one launch: :meth:`spawn` them, :meth:`run` until the launch ends
    (:meth:`pump` their output, :meth:`reap` the exits), then always :meth:`stop` (stop what
    runs, save the rest of the output); :attr:`code` is the launch's exit code (module
    docstring)."""

    def __init__(self, log_dir: str | os.PathLike, out: IO[str]) -> None:
        self.log_dir, self.out = log_dir, out
        self.selector = selectors.DefaultSelector()
        self.nodes: list[LaunchNode] = []  # in the launch file's order
        self.children: dict[str, subprocess.Popen] = {}  # label → process
        self.running: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, IO[str]] = {}
        self.code = 0

    def _say(self, text: str) -> None:
        print(f"[launch] {text}", file=self.out, flush=True)

    def spawn(self, commands: Sequence[tuple[LaunchNode, list[str]]]) -> None:
        """Start every node, its output into ``<log_dir>/<label>.log`` (and :meth:`pump`)."""
        for node, command in commands:
            self.logs[node.label] = open(  # noqa: SIM115  (closed by stop)
                os.path.join(self.log_dir, f"{node.label}.log"), "w", encoding="utf-8"
            )
            child = subprocess.Popen(
                command,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                bufsize=1,
                preexec_fn=_die_with_parent,  # noqa: PLW1509  (no threads here)
            )
            self.nodes.append(node)
            self.children[node.label] = self.running[node.label] = child
            assert child.stdout is not None
            self.selector.register(child.stdout, selectors.EVENT_READ, node)
            self._say(f"started {node.label} (pid {child.pid})")

    def pump(self, timeout: float = 0.1) -> None:
        """The lines the nodes wrote (waiting at most ``timeout`` s): into their logs, and
        prefixed ``[label]`` to the output for ``output: screen``."""
        for key, _ in self.selector.select(timeout=timeout):
            node = key.data
            line = key.fileobj.readline()  # type: ignore[union-attr]
            if not line:
                self.selector.unregister(key.fileobj)
                continue
            self.logs[node.label].write(line)
            if node.output == "screen":
                print(f"[{node.label}] {line}", end="", file=self.out, flush=True)

    def reap(self) -> bool:
        """Report the nodes that exited; the first failure's code is kept. True when one with
        ``on_exit: shutdown`` exited: the launch ends (its code, unless 0)."""
        for node in self.nodes:
            exited = self.running.get(node.label)
            if exited is None or exited.poll() is None:
                continue
            del self.running[node.label]
            self._say(f"{node.label} exited with {exited.returncode}")
            self.code = self.code or exited.returncode  # the first failure, reported at the end
            if node.shutdown_on_exit:
                self.code = exited.returncode or self.code
                self.running.clear()
                return True
        return False

    def run(self, timeout: float | None, stop: Sequence[int]) -> int:
        """Pump and reap until no node runs, a shutdown node exited, ``timeout`` wall s passed
        (code 124) or a signal arrived in ``stop`` (128 + N); the launch's exit code."""
        end = None if timeout is None else time.monotonic() + timeout
        while self.running and not stop:
            self.pump()
            self.reap()  # a shutdown node's exit empties ``running``
            if end is not None and time.monotonic() > end:
                self._say(f"time limit {timeout} s: stopping")
                self.code = 124
                break
        if stop:
            self.code = 128 + stop[0]
        return self.code

    def stop(self) -> None:
        """Stop every node (:func:`_stop`), then save what their pipes still hold (and show it
        for ``output: screen``); close the logs."""
        _stop(self.children, self.out)
        screen = {node.label for node in self.nodes if node.output == "screen"}
        for label, child in self.children.items():
            if child.stdout is not None:
                # what the pipe (or the reader's buffer: select does not see it) still holds
                rest = child.stdout.read()
                self.logs[label].write(rest)
                if label in screen:
                    for line in rest.splitlines(keepends=True):
                        print(f"[{label}] {line}", end="", file=self.out)
                    self.out.flush()
                child.stdout.close()
        for fh in self.logs.values():
            fh.close()
        self.selector.close()


def run_launch(
    description: LaunchDescription,
    *,
    log_dir: str | os.PathLike,
    out: IO[str] | None = None,
    timeout: float | None = None,
) -> int:
    """Run every node; return the exit code of the launch (module docstring).

    Args:
        log_dir: each node's output goes to ``<log_dir>/<name>.log`` (and to ``out`` for
            ``output: screen``, each line prefixed ``[name]``); the parameter files of the
            ``{name, value}`` entries are written there too.
        out: where screen output goes (default: stdout).
        timeout: wall-time limit, s (None: none); past it every node is stopped, exit 124.

    The steps: :func:`prepare_launch`, then a :class:`LaunchSession`'s; SIGINT and SIGTERM
    end the run (the previous handlers come back at the end)."""
    out = out or sys.stdout
    commands = prepare_launch(description, log_dir, out)
    stop: list[int] = []
    previous = {
        s: signal.signal(s, lambda signum, _frame: stop.append(signum))
        for s in (signal.SIGINT, signal.SIGTERM)
    }
    session = LaunchSession(log_dir, out)
    try:
        session.spawn(commands)
        return session.run(timeout, stop)
    finally:
        session.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)


def _stop(children: Mapping[str, subprocess.Popen], out: IO[str]) -> None:
    """SIGINT every running node, SIGTERM what still runs :data:`SIGTERM_TIMEOUT` s later, then
    SIGKILL after :data:`SIGKILL_TIMEOUT` s more (launch's ``ExecuteProcess`` defaults)."""
    steps = ((signal.SIGINT, SIGTERM_TIMEOUT), (signal.SIGTERM, SIGKILL_TIMEOUT))
    for signum, timeout in steps:
        waiting = {label: c for label, c in children.items() if c.poll() is None}
        for label, child in waiting.items():
            if signum != signal.SIGINT:
                print(f"[launch] {label} still running: {signum.name}", file=out, flush=True)
            with contextlib.suppress(ProcessLookupError):
                child.send_signal(signum)
        end = time.monotonic() + timeout
        for child in waiting.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.wait(timeout=max(0.0, end - time.monotonic()))
    for label, child in children.items():
        if child.poll() is None:
            print(f"[launch] {label} still running: SIGKILL", file=out, flush=True)
            child.kill()
            child.wait()


def parse_launch_arguments(items: Sequence[str]) -> dict[str, str]:
    """``name:=value`` items (as ``ros2 launch`` takes them)."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name:
            raise LaunchError(f"launch argument {item!r}: expected NAME:=VALUE")
        out[name] = value
    return out


def find_launch_file(name: str, package: str = "ffmpc_ros") -> str:
    """A path as given, or a file name under ``share/<package>/launch`` (as ``ros2 launch PKG
    FILE`` finds it)."""
    if os.path.sep in name or os.path.isfile(name):
        return name
    path = os.path.join(package_prefix(package), "share", package, "launch", name)
    if not os.path.isfile(path):
        raise LaunchError(f"no launch file {name!r} in {os.path.dirname(path)}")
    return path


def add_launch_parser(sub: argparse._SubParsersAction) -> None:
    """``ffmpc launch FILE [name:=value ...]``."""
    from ffmpc_ros.cli_args import positive_float

    p = sub.add_parser(
        "launch",
        help="run a ROS 2 YAML launch file (a subset of ros2 launch; no launch_ros needed)",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
    )
    p.add_argument("file", help="a .launch.yaml path, or a file name in share/ffmpc_ros/launch")
    p.add_argument("arguments", nargs="*", metavar="NAME:=VALUE", help="launch arguments")
    p.add_argument(
        "--log-dir",
        help="the nodes' log files (default: a new temporary directory); an existing directory "
        "that holds files is refused unless --force",
    )
    p.add_argument("--force", action="store_true", help="write into a --log-dir that has files")
    p.add_argument("--timeout", type=positive_float, default=None, help="wall-time limit, s")
    p.add_argument("--show-args", action="store_true", help="print the arguments and exit")
    p.set_defaults(func=_cmd_launch, needs_ros=True)


def _check_log_dir(path: str, force: bool) -> None:
    """``--log-dir``: a new directory in a writable one, or an existing writable directory that
    is empty (or any, with ``--force``: the nodes' logs there are replaced)."""
    from ffmpc_ros.preflight import check_output

    log_dir = Path(path)
    if not log_dir.exists():
        check_output(log_dir, what="--log-dir")
        return
    if not log_dir.is_dir():
        raise LaunchError(f"--log-dir {path}: not a directory")
    if any(log_dir.iterdir()) and not force:
        raise LaunchError(
            f"--log-dir {path}: holds files; never overwritten (--force writes there)"
        )
    check_output(log_dir / "launch.log", what="--log-dir")


def _cmd_launch(args: argparse.Namespace) -> int:
    import tempfile

    path = find_launch_file(args.file)
    description = load_launch_file(path, parse_launch_arguments(args.arguments))
    if args.show_args:
        for name, value in description.arguments.items():
            print(f"{name}:={value}")
        return 0
    check_launch(description)
    if args.log_dir:
        _check_log_dir(args.log_dir, args.force)
    log_dir = args.log_dir or tempfile.mkdtemp(prefix="ffmpc_launch_")
    print(f"[launch] {path}: {len(description.nodes)} nodes, logs in {log_dir}", flush=True)
    return run_launch(description, log_dir=log_dir, timeout=args.timeout)
