"""The robot's frame tree as robot_state_publisher sees it, computed with pinocchio.

robot_state_publisher reads the URDF's joints (parent link → child link) and publishes, for every
joint, the child link's placement in the parent link: the fixed joints once on ``/tf_static``,
the moving ones on ``/tf`` from the joint states. This module gives the same edges for an
:class:`~ffmpc_core.robots.RobotModel`, their placements from pinocchio's forward kinematics of
the model built from that URDF (``BODY`` frames are named like the URDF links):

* one edge per URDF joint whose two links are in the model, static when the joint is ``fixed``
  in the URDF or is not a joint of the model (the Panda's finger joints, locked at the model's
  reference configuration: a fixed transform there);
* ``world`` → the URDF's root link, static identity: pinocchio's world is the robot's fixed base
  (the plant puts the base at the world origin);
* ``<flange link>`` → ``contact``, static: the contact/tool frame of the model (not in the URDF);
* ``world`` → ``contact_world_aligned``, moving: the contact frame's origin with the world's
  axes, the frame_id of every wrench of the graph (``ffmpc_ros.topics.WRENCH_FRAME``), so a
  ``WrenchStamped`` can be shown and transformed by tf2.

Units: m, unit quaternions (x, y, z, w) as geometry_msgs. No ROS here: the node
(``ffmpc_ros.state_publisher_node``) turns the edges into messages.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from ffmpc_core.errors import ConfigError
from ffmpc_core.robots import RobotModel

#: The root frame of the tree (pinocchio's universe: the robot's fixed base).
WORLD_FRAME = "world"
#: The frame of the wrenches: contact frame origin, world axes (ffmpc_ros.topics.WRENCH_FRAME).
CONTACT_WORLD_ALIGNED = "contact_world_aligned"


@dataclass(frozen=True)
class Edge:
    """One transform of the tree: ``child``'s placement in ``parent``.

    ``parent_id``/``child_id`` are frame ids of the pinocchio model (-1: the world);
    ``world_aligned``: the child has the world's axes (only its origin moves)."""

    parent: str
    child: str
    parent_id: int
    child_id: int
    static: bool
    world_aligned: bool = False


def urdf_joints(urdf_path: str) -> list[tuple[str, str, str, str]]:
    """(joint name, type, parent link, child link) of every joint of a URDF, in file order."""
    try:
        root = ET.parse(urdf_path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ConfigError(f"cannot read the URDF {urdf_path}: {exc}") from None
    out = []
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise ConfigError(f"{urdf_path}: joint {joint.get('name')!r} has no parent or child")
        link = (parent.get("link", ""), child.get("link", ""))
        out.append((joint.get("name", ""), joint.get("type", ""), *link))
    return out


def robot_edges(robot: RobotModel) -> list[Edge]:
    """The edges of the tree of ``robot`` (module docstring), static ones first."""
    model = robot.model
    moving_joints = set(model.names[1:])

    def body(name: str) -> int | None:
        return model.getFrameId(name, pin.BODY) if model.existBodyName(name) else None

    edges: list[Edge] = []
    children: set[str] = set()
    for name, kind, parent, child in urdf_joints(robot.urdf_path):
        pid, cid = body(parent), body(child)
        if pid is None or cid is None:
            continue  # a link the model does not have (none in the shipped robots)
        children.add(child)
        static = kind == "fixed" or name not in moving_joints
        edges.append(Edge(parent, child, pid, cid, static))
    roots = [
        f.name for f in model.frames if f.type == pin.FrameType.BODY and f.name not in children
    ]
    if len(roots) != 1:
        raise ConfigError(f"{robot.name}: expected one root link in the URDF, found {roots}")
    contact = robot.contact_frame_id
    root_id = model.getFrameId(roots[0], pin.BODY)
    flange_id = model.getFrameId(robot.flange_frame, pin.BODY)
    edges.append(Edge(WORLD_FRAME, roots[0], -1, root_id, True))
    edges.append(Edge(robot.flange_frame, model.frames[contact].name, flange_id, contact, True))
    edges.append(Edge(WORLD_FRAME, CONTACT_WORLD_ALIGNED, -1, contact, False, world_aligned=True))
    return sorted(edges, key=lambda e: not e.static)


def edge_placements(
    robot: RobotModel, data: pin.Data, q: np.ndarray, edges: list[Edge]
) -> list[pin.SE3]:
    """The placement of each edge's child in its parent at configuration q (rad), by
    pinocchio's forward kinematics (m, rad)."""
    pin.framesForwardKinematics(robot.model, data, q)
    out = []
    for e in edges:
        child = data.oMf[e.child_id]
        if e.world_aligned:
            placement = pin.SE3(np.eye(3), child.translation.copy())
        else:
            placement = pin.SE3(child) if e.parent_id < 0 else data.oMf[e.parent_id].actInv(child)
        out.append(placement)
    return out


def description_with_absolute_meshes(urdf_path: str) -> str:
    """The URDF text with every relative mesh filename made an absolute ``file://`` URI and
    every ``package://PKG/...`` one resolved on disk when found (Foxglove and RViz fetch both)."""
    base = Path(urdf_path).resolve().parent
    text = Path(urdf_path).read_text(encoding="utf-8")

    def resolve(match: re.Match) -> str:
        name = match.group(2)
        if name.startswith("package://"):
            rest = name[len("package://") :]
            for parent in [base, *base.parents]:
                if (parent / rest).is_file():
                    return f"{match.group(1)}file://{parent / rest}{match.group(3)}"
                if (parent.parent / rest).is_file():
                    return f"{match.group(1)}file://{parent.parent / rest}{match.group(3)}"
            return match.group(0)
        if "://" in name:
            return match.group(0)
        return f"{match.group(1)}file://{(base / name).resolve()}{match.group(3)}"

    return re.sub(r'(filename\s*=\s*")([^"]+)(")', resolve, text)
