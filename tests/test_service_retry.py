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
