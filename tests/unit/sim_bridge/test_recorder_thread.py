"""The recorder's writer thread: callers only queue; everything queued is written, in order;
what a full queue cannot take is counted and said on the log."""

from __future__ import annotations

import threading
from pathlib import Path

from mcap.reader import make_reader

from runtime.wire import keys
from runtime.wire.messages import Command, encode_command
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder
from sim_bridge.log.schemas import parse


def cmd(rid: int, step: int) -> bytes:
    return encode_command(Command(rid, step, 0.1, 0.0, "rule:assign", False, 0.0, 5.0))


def commands_in(path: Path) -> dict[int, list[int]]:
    """Robot -> steps of its commands, in the file's order."""
    out: dict[int, list[int]] = {}
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            if channel.topic.endswith("/cmd"):
                c = parse(schema.name, msg.data)
                out.setdefault(c.robot_id, []).append(c.step)
    return out


def test_everything_queued_from_many_threads_is_written(tmp_path: Path) -> None:
    path = tmp_path / "t.mcap"
    rec = Recorder(path, threaded=True)

    def robot(rid: int) -> None:
        for step in range(50):
            rec.write_wire(keys.cmd_key("s", rid), cmd(rid, step))

    threads = [threading.Thread(target=robot, args=(r,)) for r in range(4)]
    for t in threads:
        t.start()
    for step in range(50):
        rec.metrics({"step": step, "time_s": step * 0.1, "n_live": 4, "formation_error_m": 1.0,
                     "min_separation_m": 1.0})
    for t in threads:
        t.join()
    rec.event("run_end", 50, 5.0, outcome="done")
    rec.flush()  # waits for the writer: what was queued is in the file now
    assert rec.messages_written >= 4 * 50 + 50 + 1
    assert rec.writer_cpu_s > 0.0  # the writer's own CPU, counted on its thread
    rec.close()
    run = read_log(path)
    assert run.recovery.finished and rec.dropped == 0
    assert commands_in(path) == {r: list(range(50)) for r in range(4)}  # each thread's order
    assert [e["kind"] for e in run.events] == ["run_end"]


def test_a_full_queue_drops_counts_and_says_so(tmp_path: Path) -> None:
    path = tmp_path / "d.mcap"
    rec = Recorder(path, threaded=True, queue_items=5)
    with rec._lock:  # the writer is stuck on the file: the queue fills up
        for step in range(40):
            rec.write_wire(keys.cmd_key("s", 1), cmd(1, step))
        dropped = rec.dropped
    assert dropped >= 40 - 5 - 1  # at most the queue and the message being written got in
    rec.close()
    run = read_log(path)
    (ev,) = run.events_of("log_dropped")
    assert ev["dropped"] == dropped
    assert sum(map(len, commands_in(path).values())) == 40 - dropped
