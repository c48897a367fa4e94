"""Fault tests: each on its own ROS 2 domain.

A graph that has just exited stays in DDS discovery for a few seconds, and ``ffmpc run``
refuses to start beside nodes of its graph's names or topics (a leftover or second graph): a
run started by the next test on the same domain was refused for the previous test's ``/mpc`` and
``/metrics`` (seen in a fresh clone's CI run). Tests that want two graphs on one domain start
both within the test.
"""

from __future__ import annotations

import itertools
import os

import pytest

_next = itertools.count(1)


@pytest.fixture(autouse=True)
def own_ros_domain(monkeypatch):
    """Set ROS_DOMAIN_ID to a domain of this test alone (1..100, never the session's)."""
    base = int(os.environ.get("ROS_DOMAIN_ID", "0"))
    domain = base
    while domain == base:
        domain = 1 + (base + next(_next)) % 100
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    return domain
