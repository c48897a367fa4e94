"""What a node process hands back to the bring-up when it ends: a small JSON file with a schema.

The bring-up (``ffmpc run``, ``ffmpc run impact``) gives every node process it spawns the graph
parameter ``results_file`` (a path in the run's temporary directory); the node writes, as it
exits (:func:`ffmpc_ros.base.run_node`), ``{"schema": SCHEMA, "node": name, "rejected": {kind:
count}}`` there (:func:`write_node_results`), and the bring-up reads it back
(:func:`read_node_results`) instead of parsing the process's log. The file is written whole
(a temporary file renamed over it), so a reader never sees half of one.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping

from ffmpc_core.errors import FfmpcError

#: The format of a node's results file (bumped on any change of its fields).
SCHEMA = "ffmpc.node_results/1"


class NodeResultsError(FfmpcError):
    """A node's results file that is not one (wrong schema, fields or types)."""


def write_node_results(path: str | os.PathLike, node: str, rejected: Mapping[str, int]) -> None:
    """Write node ``node``'s results (its rejected-input counts by kind) to ``path``."""
    doc = {
        "schema": SCHEMA,
        "node": node,
        "rejected": {str(k): int(v) for k, v in rejected.items()},
    }
    tmp = f"{os.fspath(path)}.tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(doc, fh)
    os.replace(tmp, path)


def read_node_results(path: str | os.PathLike) -> tuple[str, dict[str, int]] | None:
    """``(node, {kind: count})`` of a results file; None when the node wrote none (it did not
    end normally). NodeResultsError for a file that does not have the schema."""
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise NodeResultsError(f"{path}: not a node results file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        raise NodeResultsError(f"{path}: not a node results file (schema {SCHEMA} expected)")
    node, rejected = doc.get("node"), doc.get("rejected")
    if not isinstance(node, str) or not isinstance(rejected, dict):
        raise NodeResultsError(f"{path}: a node results file needs 'node' and 'rejected'")
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in rejected.values()):
        raise NodeResultsError(f"{path}: rejected counts must be integers")
    return node, {str(k): v for k, v in rejected.items()}
