"""The committed Foxglove layout of the live view (``share/ffmpc_ros/foxglove/ffmpc_layout.json``).

Built here with ``foxglove.layouts`` (foxglove-sdk) and written by ``python -m
ffmpc_ros.view_layout``; ``tests/test_live_view.py`` checks that the committed file is this
layout. Every panel names ROS topics only, so the layout opens the live server of ``ffmpc run
--view`` and a bag of ``ffmpc run --record`` alike:

* 3D: the URDF of ``/robot_description`` driven by ``/plant/joint_states`` (Foxglove computes
  the link transforms itself, so a bag needs no ``/tf``), the markers of ``/view/markers`` (force
  arrow, planned path); the display frame is the root link of the polishing scenario's robot;
* normal force: measured (``/ft_sensor/wrench``, world z), true (``/plant/truth``) and the
  MPC's reference at node 0 (``/mpc/prediction``), N;
* predicted force: the MPC's normal force at node 0, node 1 and the end of the horizon, N.

Indices into ``/mpc/prediction`` follow layout ``mpc_prediction`` for the horizon of the shipped
scenarios (:data:`NODES` = N + 1); another horizon moves the reference and the last node.
The topics are those of a graph at the root namespace (``ffmpc run`` without ``--namespace``).
"""

from __future__ import annotations

import json
from pathlib import Path

from ffmpc_ros import layouts, topics

#: N + 1 of the shipped scenarios' MPC (mpc.horizon: 5).
NODES = 6
#: The display frame: the root link of the iiwa (the polishing scenario's robot).
DISPLAY_FRAME = "lbr_iiwa_link_0"


def _prediction_index(field: str, node: int) -> int:
    return layouts.MPC_PREDICTION.slices(nodes=NODES)[field].start + node


def foxglove_layout() -> dict:
    """The layout as a JSON document (module docstring)."""
    import foxglove.layouts as fl

    def series(value: str, label: str, color: str) -> fl.PlotSeries:
        return fl.PlotSeries(value=value, label=label, color=color, timestamp_method="receiveTime")

    prediction = topics.resolve(topics.MPC_PREDICTION)
    force = fl.PlotPanel(
        title="Normal force (N)",
        config=fl.PlotConfig(
            paths=[
                series(
                    f"{topics.resolve(topics.SENSED_WRENCH)}.wrench.force.z", "measured", "#e41a1c"
                ),
                series(f"{topics.resolve(topics.PLANT_TRUTH)}.data[1]", "true", "#377eb8"),
                series(
                    f"{prediction}.data[{_prediction_index('reference_force', 0)}]",
                    "reference",
                    "#4daf4a",
                ),
            ],
            show_legend=True,
        ),
    )
    predicted = fl.PlotPanel(
        title="MPC predicted normal force (N)",
        config=fl.PlotConfig(
            paths=[
                series(
                    f"{prediction}.data[{_prediction_index('normal_force', 0)}]",
                    "node 0",
                    "#984ea3",
                ),
                series(
                    f"{prediction}.data[{_prediction_index('normal_force', 1)}]",
                    "node 1",
                    "#ff7f00",
                ),
                series(
                    f"{prediction}.data[{_prediction_index('normal_force', NODES - 1)}]",
                    f"node {NODES - 1} (end of horizon)",
                    "#a65628",
                ),
            ],
            show_legend=True,
        ),
    )
    scene = fl.ThreeDeePanel(
        title="Robot, measured force, planned path",
        config=fl.ThreeDeeConfig(
            follow_tf=DISPLAY_FRAME,
            topics={
                topics.resolve(topics.ROBOT_DESCRIPTION): fl.BaseRendererUrdfTopicSettings(
                    visible=True,
                    control_mode="jointStates",
                    joint_states_topic=topics.resolve(topics.PLANT_JOINT_STATES),
                ),
                topics.resolve(topics.VIEW_MARKERS): fl.BaseRendererRosMarkerTopicSettings(
                    visible=True
                ),
            },
        ),
    )
    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3, content=scene),
                fl.SplitItem(
                    proportion=2,
                    content=fl.SplitContainer(
                        direction="column",
                        items=[fl.SplitItem(content=force), fl.SplitItem(content=predicted)],
                    ),
                ),
            ],
        )
    )
    return json.loads(layout.to_json())


def write_layout(path: str | Path) -> None:
    """Write :func:`foxglove_layout` to ``path`` (indented JSON)."""
    Path(path).write_text(json.dumps(foxglove_layout(), indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    from ffmpc_ros.ament import _ROOT, FOXGLOVE_LAYOUT, PACKAGE

    target = _ROOT.parent / "share" / PACKAGE / FOXGLOVE_LAYOUT
    write_layout(target)
    print(target)
