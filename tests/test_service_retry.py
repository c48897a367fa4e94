"""A service request whose response is lost (ROS 2's service discovery race: the server's
response writer had not matched the client's reader yet) is sent again: the recorder's
parameter fetch, which held a run's start for good when it did not retry."""

from __future__ import annotations

from rclpy.node import Node
from rclpy.task import Future

from ffmpc_ros.bag import recorder


def test_parameter_fetch_asks_again_when_a_response_is_lost(ros, monkeypatch):
    monkeypatch.setattr(recorder, "SERVICE_RETRY", 0.2)
    target = ros.add(Node("target", context=ros.context))
    target.declare_parameter("stiffness", 1500.0)
    fetch = recorder._ParameterFetch(ros.probe(), "/target")
    real = fetch.list_client
    calls: list[int] = []

    class LosesTheFirstResponse:
        def service_is_ready(self) -> bool:
            return real.service_is_ready()

        def call_async(self, request) -> Future:
            calls.append(1)
            return Future() if len(calls) == 1 else real.call_async(request)

    fetch.list_client = LosesTheFirstResponse()
    assert ros.spin_until(fetch.poll, timeout=10.0)
    assert len(calls) == 2
    assert fetch.values["stiffness"] == 1500.0


def test_parameter_fetch_records_a_declared_but_unset_array_parameter(ros, tmp_path):
    """A node with a typed parameter declared without a value (the impact planner's
    ``acceleration_limit`` under plain ``ros2 run``) answers get_parameters with
    PARAMETER_NOT_SET: the fetch keeps every parameter, the unset one as None, and the bag
    records it as unset (JSON null) beside the others."""
    from rclpy.parameter import Parameter

    from ffmpc_ros.bag.reader import BagReader
    from ffmpc_ros.bag.recorder import BagRecorder

    target = ros.add(Node("unset_target", context=ros.context))
    target.declare_parameter("acceleration_limit", Parameter.Type.DOUBLE_ARRAY)
    target.declare_parameter("stiffness", 1500.0)
    fetch = recorder._ParameterFetch(ros.probe(), "/unset_target")
    assert ros.spin_until(fetch.poll, timeout=10.0)
    assert fetch.values["acceleration_limit"] is None
    assert fetch.values["stiffness"] == 1500.0
    path = tmp_path / "unset.mcap"
    rec = ros.add(
        BagRecorder(
            path,
            context=ros.context,
            topics=[],
            parameters_of=["unset_target"],
            use_sim_time=False,
        )
    )
    assert ros.spin_until(lambda: "/unset_target" in rec.parameters, timeout=10.0)
    rec.close()
    params = BagReader(path).parameters["/unset_target"]
    assert params["acceleration_limit"] is None
    assert params["stiffness"] == 1500.0
