"""``BagStudy.matches_recorded``: the recomputed summary against the one recorded in a bag."""

from __future__ import annotations

import numpy as np

from ffmpc_core.metrics import PolishingMetrics
from ffmpc_ros.bag.analysis import BagStudy


def _study(recorded: dict | None, force_mae: float = 1.25) -> BagStudy:
    metrics = PolishingMetrics(
        position_mae_mm=3.0,
        force_mae=force_mae,
        max_force=55.0,
        contact_break_percent=0.0,
        torque_mae=2.0,
    )
    return BagStudy(
        bag="run.mcap",
        formulation="force_feedback",
        seed=0,
        cycles=100,
        recorded_cycles=100,
        filled=0,
        log={},
        table_normal=np.array([0.0, 0.0, 1.0]),
        metrics_true=metrics,
        metrics_measured=metrics,
        recorded_summary=recorded,
        contact_time=0.84,
    )


def test_a_recorded_summary_without_the_newer_keys_still_matches_and_a_changed_metric_does_not():
    full = _study(None).summary()
    older = {k: v for k, v in full.items() if k not in ("contact_time_s", "contact_missed")}
    assert _study(full).matches_recorded is True
    assert _study(older).matches_recorded is True  # recorded before those keys existed
    assert _study(older, force_mae=1.26).matches_recorded is False
    assert _study({**full, "contact_time_s": 0.9}).matches_recorded is False
    assert _study(None).matches_recorded is None
