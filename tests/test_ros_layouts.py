"""msgs_notes/ is the contract: its tables must agree with ffmpc_ros/layouts.py and topics.py,
and the layouts must pack, unpack and reject exactly as documented."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import InputError
from ffmpc_ros import layouts, topics

NOTES = Path(__file__).resolve().parents[1] / "msgs_notes"


def _table_rows(text: str) -> list[list[str]]:
    rows = []
    for line in text.splitlines():
        if line.startswith("|") and not re.match(r"^\|\s*-", line):
            rows.append([c.strip().strip("`") for c in line.strip().strip("|").split("|")])
    return rows


def _layout_sections() -> dict[str, tuple[int, str, list[list[str]]]]:
    text = (NOTES / "layouts.md").read_text(encoding="utf-8")
    sections = {}
    for match in re.finditer(
        r"^## (\w+) \(version (\d+)\) — `([^`]+)`\n(.*?)(?=^## |\Z)", text, re.M | re.S
    ):
        name, version, topic, body = match.groups()
        rows = _table_rows(body)
        assert rows[0] == ["field", "size", "unit", "meaning"], f"{name}: table header"
        sections[name] = (int(version), topic, rows[1:])
    return sections


def test_every_layout_is_documented_field_by_field():
    sections = _layout_sections()
    assert set(sections) == set(layouts.LAYOUTS)
    topic_of = {
        "plant_truth": topics.PLANT_TRUTH,
        "plant_status": topics.PLANT_STATUS,
        "lowlevel_status": topics.LOWLEVEL_STATUS,
        "contact_estimate": topics.CONTACT_ESTIMATE,
        "impact_status": topics.IMPACT_STATUS,
        "impact_reference": topics.IMPACT_REFERENCE,
        "impact_control": topics.IMPACT_CONTROL_STATUS,
        "mpc_prediction": topics.MPC_PREDICTION,
    }
    for name, layout in layouts.LAYOUTS.items():
        version, topic, rows = sections[name]
        assert version == layout.version and topic == topic_of[name]
        documented = [(r[0], r[1], r[2], r[3]) for r in rows]
        in_code = [(f.name, str(f.size), f.unit, f.meaning) for f in layout.fields]
        assert documented == in_code, f"msgs_notes/layouts.md disagrees with layouts.{name}"


def test_every_topic_is_documented_with_its_type_and_publisher():
    rows = _table_rows((NOTES / "topics.md").read_text(encoding="utf-8"))
    topic_rows = [r for r in rows if len(r) == 7 and "/msg/" in r[1]]
    documented = {(r[0], r[1], r[2]) for r in topic_rows}
    references = set(topics.REFERENCE_TOPICS)
    documented_sets = (
        set(topics.TOPICS)
        | set(topics.IMPACT_TOPICS)
        | set(topics.IMPACT_GRAPH_TOPICS)
        | set(topics.VIEW_TOPICS)
        | set(topics.ROS2_CONTROL_TOPICS)
    )
    assert documented == documented_sets | references
    assert len(topic_rows) == len(documented_sets) + len(references)
    services = (
        topics.TARE_SERVICE,
        topics.IMPACT_RESET_SERVICE,
        topics.CONTACT_LEARNER_RESET_SERVICE,
    )
    for service in services:
        assert any(r[0] == service and r[1] == "std_srvs/srv/Trigger" for r in rows), service
    readme = (NOTES / "README.md").read_text(encoding="utf-8")
    assert topics.WRENCH_FRAME in readme and str(topics.PUBLISHER_DEPTH) in readme
    # each row's QoS column names the topic's class (topics.QOS_CLASSES; /clock its own)
    for row in topic_rows:
        kind = "clock" if row[0] == topics.CLOCK else topics.qos_class(row[0])
        assert row[5].split(":")[0].split(" (")[0] == kind, row[0]
    # and the class table of README.md lists it under that class
    classes = {r[0]: r[3] for r in _table_rows(readme) if len(r) == 4}
    for row in topic_rows:
        if row[0] != topics.CLOCK:
            listed = classes[topics.qos_class(row[0])]
            assert re.search(rf"(^|`){re.escape(row[0])}(`|$)", listed), row[0]


def test_layouts_reject_wrong_label_length_and_non_finite():
    values = {f.name: np.zeros(f.length()) for f in layouts.LOWLEVEL_STATUS.fields}
    msg = layouts.LOWLEVEL_STATUS.pack(values)
    layouts.LOWLEVEL_STATUS.unpack(msg)
    with pytest.raises(InputError, match="expected a ffmpc/plant_truth/1"):
        layouts.PLANT_TRUTH.unpack(msg)
    short = Float64MultiArray(layout=msg.layout, data=list(msg.data)[:-1])
    with pytest.raises(InputError, match="elements"):
        layouts.LOWLEVEL_STATUS.unpack(short)
    bad = Float64MultiArray(layout=msg.layout, data=[float("nan")] + list(msg.data)[1:])
    with pytest.raises(InputError, match="non-finite"):
        layouts.LOWLEVEL_STATUS.unpack(bad)
    with pytest.raises(InputError, match="missing"):
        layouts.LOWLEVEL_STATUS.pack({"t": 0.0})


def test_the_typed_command_is_documented_field_by_field():
    """msgs_notes/messages.md lists every field of the generated ffmpc_msgs/MpcCommand (nested
    ones by their path) with its ROS type."""
    from ffmpc_msgs.msg import MpcCommand

    def fields(cls, prefix: str = "") -> list[tuple[str, str]]:
        out = []
        for name, ros_type in cls.get_fields_and_field_types().items():
            nested = {"ffmpc_msgs/Matrix", "ffmpc_msgs/LinearizationState"}
            if ros_type in nested:
                sub = getattr(MpcCommand(), name).__class__
                out += fields(sub, f"{prefix}{name}.")
            elif ros_type == "std_msgs/Header":
                out += [(f"{prefix}{name}.stamp", "builtin_interfaces/Time")]
                out += [(f"{prefix}{name}.frame_id", "string")]
            else:
                ros_type = ros_type.replace("sequence<double>", "float64[]")
                ros_type = ros_type.replace("sequence<string>", "string[]")
                ros_type = {"double": "float64", "octet": "uint8", "boolean": "bool"}.get(
                    ros_type, ros_type
                )
                out.append((f"{prefix}{name}", ros_type))
        return out

    text = (NOTES / "messages.md").read_text(encoding="utf-8")
    section = text[text.index("## MpcCommand (version 2) — `mpc/command`") :]
    rows = [r for r in _table_rows(section) if len(r) == 5][1:]
    documented = [(r[0], r[1]) for r in rows if r[0] != "VERSION"]
    assert documented == fields(MpcCommand)
    assert MpcCommand.VERSION == 2
