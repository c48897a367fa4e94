"""Bad input through the real entry points (issue 28): the ``ffmpc`` command line as a
subprocess (``bad_input_helpers.run_cases``), messages through a real rclpy publisher.
:func:`workdir` makes the files the command-line cases use, once per module."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from bad_input_helpers import BAG, truncate


def _first_chunk_offset(path: Path) -> int:
    """Byte offset of the first chunk record of an indexed MCAP file (its summary)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes
    return min(c.chunk_start_offset for c in summary.chunk_indexes)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """The files of the cases: existing outputs, a truncated bag, an empty bag, scenarios."""
    from ffmpc_ros.bag.reader import recover_bag

    root = tmp_path_factory.mktemp("bad_input")
    (root / "existing.json").write_text('{"keep": "me"}\n')
    shutil.copy(BAG, root / "existing.mcap")
    shutil.copy(BAG, root / "run.mcap")
    truncate(BAG, root / "trunc.mcap", 400_000)  # a few complete chunks of the reference bag
    # inside the first chunk: no complete chunk, 0 readable messages (wherever the chunk starts)
    truncate(BAG, root / "trunc0.mcap", _first_chunk_offset(BAG) + 64)
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


@pytest.fixture(scope="module")
def truncated_counts(workdir) -> dict[str, int]:
    """What ``trunc.mcap`` really holds, counted with mcap's own stream reader (records read
    until the cut): ``messages`` in its ``chunks`` complete chunks, of ``total`` in the whole
    bag's summary. The refusals must name these numbers."""
    from mcap.exceptions import McapError
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader, breakup_chunk

    messages = chunks = 0
    with open(workdir / "trunc.mcap", "rb") as fh:
        try:
            for record in StreamReader(fh, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    chunks += 1
                    messages += sum(type(r).__name__ == "Message" for r in breakup_chunk(record))
        except (McapError, EOFError, ValueError):
            pass  # the cut: the chunk it falls in is not complete
    from mcap.reader import make_reader

    with open(BAG, "rb") as fh:
        summary = make_reader(fh).get_summary()
    total = sum(summary.statistics.channel_message_counts.values()) if summary else 0
    assert 0 < messages < total, (messages, total)
    return {"messages": messages, "chunks": chunks, "total": total}
