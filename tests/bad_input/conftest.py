"""Bad input through the real entry points (issue 28): the ``ffmpc`` command line as a
subprocess (``bad_input_helpers.run_cases``), messages through a real rclpy publisher.
:func:`workdir` makes the files the command-line cases use, once per module."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from bad_input_helpers import BAG, truncate


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """The files of the cases: existing outputs, a truncated bag, an empty bag, scenarios."""
    from ffmpc_ros.bag.reader import recover_bag

    root = tmp_path_factory.mktemp("bad_input")
    (root / "existing.json").write_text('{"keep": "me"}\n')
    shutil.copy(BAG, root / "existing.mcap")
    shutil.copy(BAG, root / "run.mcap")
    truncate(BAG, root / "trunc.mcap", 400_000)  # 2775 readable messages of 6110
    truncate(BAG, root / "trunc0.mcap", 100_000)  # no complete chunk: 0 readable messages
    recover_bag(root / "trunc0.mcap", root / "empty.mcap")  # complete, 0 messages
    (root / "empty.yaml").write_text("")
    (root / "partial.yaml").write_text("/**/mpc:\n  ros__parameters:\n    horizon: 7\n")
    (root / "sci.yaml").write_text(
        "/**:\n  ros__parameters:\n    base: polishing\n"
        "/**/mpc:\n  ros__parameters:\n    contact: {stiffness: 1e4}\n"
    )
    (root / "mixed.yaml").write_text(
        "/**:\n  ros__parameters:\n    base: polishing\n"
        "/**/plant:\n  ros__parameters:\n    table_tilt_axis: [0, 1.0, 0]\n"
    )
    (root / "outdir").mkdir()
    (root / "outdir" / "old.log").write_text("old\n")
    return root
