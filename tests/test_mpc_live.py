"""The MPC node's rules for what changes its OCP while it runs (ffmpc_ros.mpc_live), alone: the
live-parameter rules, the reference target's checks, the learned contact's direction and
confidence rules (the node's own tests drive them through topics)."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import PoseStamped

from ffmpc_core.impact.learner import ContactEstimate
from ffmpc_core.polishing import mpc_config
from ffmpc_core.scenario import load_scenario
from ffmpc_ros.mpc_live import LearnedContact, Refusal, live_refusal, reference_offset


def test_live_rules_follow_the_formulation_and_the_task() -> None:
    ff = ("force_feedback", "polishing", True, 50.0)
    assert live_refusal("contact.stiffness", 1e4, *ff) is None
    assert "no visco-elastic contact" in str(
        live_refusal("contact.stiffness", 1e4, "classical", "polishing", True, 50.0)
    )
    assert "not classical" in str(live_refusal("weights.classical.torque", 1.0, *ff))
    assert live_refusal("weights.force_feedback.force_rate", 1.0, *ff) is None
    assert "force-rate" in str(
        live_refusal("weights.classical.force_rate", 1.0, "classical", "x", True, 50.0)
    )
    assert "no single positive force" in str(
        live_refusal("task.normal_force", 30.0, "classical", "reach", False, 0.0)
    )


def _pose(target, frame: str = "world", sec: int = 0) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.header.stamp = TimeMsg(sec=sec, nanosec=0)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, target)
    return msg


def test_a_reference_target_becomes_an_offset_or_is_refused_with_its_kind() -> None:
    nominal = np.array([0.5, 0.0, 0.3])
    offset = reference_offset(_pose(nominal + [0.03, 0.0, -0.01]), nominal, now_ns=0)
    assert not isinstance(offset, Refusal)
    np.testing.assert_allclose(offset, [0.03, 0.0, -0.01], atol=1e-15)
    assert reference_offset(_pose(nominal, frame="tool"), nominal, 0).kind == "frame"
    assert reference_offset(_pose(nominal, sec=1), nominal, 0).kind == "future"
    assert reference_offset(_pose(nominal, sec=1), nominal, 1_000_000_000) is not None
    assert reference_offset(_pose([np.nan, 0.0, 0.3]), nominal, 0).kind == "value"
    far = reference_offset(_pose(nominal + [0.5, 0.0, 0.0]), nominal, 0)
    assert isinstance(far, Refusal) and far.kind == "workspace"


def _estimate(stiffness: float, damping: float, samples: int, std: float) -> ContactEstimate:
    return ContactEstimate(
        stiffness=stiffness,
        damping=damping,
        stiffness_std=std * stiffness,
        damping_std=std * damping,
        noise_std=0.1,
        samples=samples,
        condition=10.0,
    )


class _Mpc:
    """The controller's contact setter, recorded."""

    def __init__(self) -> None:
        self.set: list[tuple[np.ndarray, np.ndarray]] = []

    def set_contact_parameters(self, stiffness, damping) -> None:
        self.set.append((np.array(stiffness), np.array(damping)))


def test_learned_contact_takes_confident_estimates_along_its_normal_axis_only() -> None:
    config = mpc_config(load_scenario("polishing", {"mpc.formulation": "force_feedback"}))
    learned = LearnedContact(config, min_samples=50, max_relative_std=0.1)
    axis = config.contact.normal_axis
    mpc = _Mpc()
    assert not learned.apply(mpc, _estimate(3000.0, 40.0, samples=10, std=0.01))  # too few
    assert not learned.apply(mpc, _estimate(3000.0, 40.0, samples=100, std=0.5))  # too unsure
    assert mpc.set == [] and learned.updates == 0
    assert learned.apply(mpc, _estimate(3000.0, 40.0, samples=100, std=0.01))
    entry = 0 if config.contact.dimension == 1 else axis
    assert mpc.set[-1][0][entry] == 3000.0 and mpc.set[-1][1][entry] == 40.0
    assert learned.updates == 1 and learned.stiffness[entry] == 3000.0
    direction = np.zeros(3)
    direction[axis] = -1.0
    if config.contact.frame_type == "LOCAL_WORLD_ALIGNED":
        assert learned.direction_refusal(direction) is None
        direction = np.roll(direction, 1)
        refusal = learned.direction_refusal(direction)
        assert refusal is not None and refusal.kind == "direction"
    else:  # a contact in its own frame takes an estimate along any direction
        assert learned.direction_refusal(np.roll(direction, 1)) is None
