"""``patternrl swap``: hot-swap the brain of running robots and report every answer.

1. Reads the brain (:func:`runtime.brain.brain.read_brain_file`): ``rule:assign``,
   or an ``.onnx`` with its manifest (the sidecar ``<stem>.json``, else the
   ONNX metadata). The robots are the judges
   of a brain, so by default nothing else is checked here (``--check``
   validates it locally first and refuses to send an invalid one).
2. Finds the robots of the swarm by their liveliness tokens
   (``patternrl/<swarm>/alive/<id>``) during ``--discover-s``, keeping those
   named by ``--robots`` (``0-9``, ``1,3,5``, ``0-3,7``; default all).
3. Publishes one :class:`runtime.wire.messages.BrainMsg` addressed to them (re-sent
   every ``--resend-s`` to robots that have not answered: a robot answers a
   repeated request again without swapping twice), and waits up to
   ``--timeout-s`` for every addressed robot's status answer.
4. Prints a table (robot, old brain, new brain, accepted or the reason
   refused), or JSON with ``--json``.

Exit codes: 0 when every addressed robot accepted; 1 when any refused or did
not answer in time, or no robot was found; 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
import uuid
from dataclasses import asdict, dataclass
from typing import Any

import zenoh

from runtime.brain.brain import BrainError, open_brain, read_brain_file, short_id
from runtime.errors import InputError
from runtime.net.session import ZenohSetupError, add_zenoh_arguments, open_session_from_args
from runtime.wire import keys
from runtime.wire.messages import BrainMsg, MessageError, decode_status, encode_brain

__all__ = ["SwapAnswer", "add_arguments", "parse_robots", "read_brain", "run", "swap_brain"]


@dataclass
class SwapAnswer:
    robot: int
    old_brain: str = ""
    new_brain: str = ""
    accepted: bool = False
    reason: str = ""
    answered: bool = False


def parse_robots(spec: str) -> set[int]:
    """``0-9``, ``1,3,5`` or ``0-3,7`` -> a set of robot ids."""
    out: set[int] = set()
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if lo < 0 or hi < lo:
                    raise ValueError
                out.update(range(lo, hi + 1))
            else:
                v = int(part)
                if v < 0:
                    raise ValueError
                out.add(v)
        except ValueError:
            raise InputError(f"bad --robots {spec!r}: expected e.g. 0-9, 1,3,5 or 0-3,7") from None
    if not out:
        raise InputError(f"bad --robots {spec!r}: names no robot")
    return out


def read_brain(ref: str, check: bool = False) -> tuple[str, bytes, str]:
    """(manifest_json, onnx_bytes, brain_id) to send for ``ref``; BrainError if unreadable.

    ``check``: validate the brain here as a robot would (raises BrainError).
    """
    brain = read_brain_file(ref)
    if check:
        open_brain(brain)
    return brain.wire_manifest(), brain.data, brain.brain_id


def _discover(
    session: zenoh.Session, swarm: str, wanted: set[int] | None, window_s: float
) -> set[int]:
    """Robot ids whose liveliness tokens are seen within ``window_s``."""
    found: set[int] = set()
    lock = threading.Lock()
    done = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        key = keys.parse_key(str(sample.key_expr))
        if key is None or key.kind != keys.ALIVE or key.robot_id is None:
            return  # the world's token, or not a key of ours
        with lock:
            found.add(key.robot_id)
            if wanted is not None and wanted <= found:
                done.set()

    alive = keys.all_alive(swarm)
    with session.liveliness().declare_subscriber(alive, on_token, history=True):
        done.wait(window_s)
    with lock:
        return set(found)


def swap_brain(
    session: zenoh.Session,
    swarm: str,
    manifest_json: str,
    onnx_bytes: bytes,
    robots: set[int] | None = None,
    timeout_s: float = 10.0,
    discover_s: float = 1.0,
    resend_s: float = 2.0,
) -> dict[int, SwapAnswer]:
    """Send a brain to the swarm's robots and collect their answers (robot -> answer)."""
    alive = _discover(session, swarm, robots, discover_s)
    targets = sorted(alive if robots is None else robots)
    answers: dict[int, SwapAnswer] = {r: SwapAnswer(r) for r in targets}
    if not targets:
        return answers
    request_id = f"swap-{uuid.uuid4().hex[:16]}"
    lock = threading.Lock()
    all_in = threading.Event()

    def on_status(sample: zenoh.Sample) -> None:
        try:
            st = decode_status(sample.payload.to_bytes())
        except MessageError:
            return
        if st.swap_request_id != request_id:
            return
        with lock:
            a = answers.get(st.robot_id)
            if a is None or a.answered:
                return
            a.old_brain, a.new_brain = st.old_brain_id, st.brain_id
            a.accepted, a.reason, a.answered = st.swap_accepted, st.swap_reason, True
            if all(x.answered for x in answers.values()):
                all_in.set()

    with session.declare_subscriber(keys.all_status(swarm), on_status):
        deadline = time.monotonic() + timeout_s
        pending = list(targets)
        while True:
            payload = encode_brain(BrainMsg(request_id, manifest_json, onnx_bytes, tuple(pending)))
            session.put(keys.brain_key(swarm), payload)
            left = deadline - time.monotonic()
            if all_in.wait(max(0.0, min(resend_s, left))) or left <= resend_s:
                break
            with lock:
                pending = [r for r, a in answers.items() if not a.answered]
            if not pending:
                break
        all_in.wait(max(0.0, deadline - time.monotonic()))
    with lock:
        return {r: SwapAnswer(**asdict(a)) for r, a in answers.items()}


def _result(a: SwapAnswer, timeout_s: float) -> str:
    if not a.answered:
        return f"no answer in {timeout_s:g} s"
    if a.accepted:
        return "accepted" + (f" ({a.reason})" if a.reason else "")
    return f"refused: {a.reason}"


def format_table(answers: dict[int, SwapAnswer], timeout_s: float) -> str:
    rows = [("robot", "old brain", "new brain", "result")]
    for r in sorted(answers):
        a = answers[r]
        rows.append(
            (
                str(r),
                short_id(a.old_brain) if a.answered else "-",
                short_id(a.new_brain) if a.answered else "-",
                _result(a, timeout_s),
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    lines = ["  ".join(row[i].ljust(widths[i]) for i in range(3)) + "  " + row[3] for row in rows]
    return "\n".join(line.rstrip() for line in lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--swarm", required=True, help="swarm name")
    parser.add_argument(
        "--brain", required=True, help="path to .onnx (manifest beside it) or rule:assign"
    )
    parser.add_argument(
        "--robots", default=None, help="which robots: 0-9, 1,3,5 or 0-3,7 (default: all alive)"
    )
    parser.add_argument(
        "--timeout-s", type=float, default=10.0, help="wait this long for answers (default 10)"
    )
    parser.add_argument(
        "--discover-s",
        type=float,
        default=1.0,
        help="look for live robots this long (default 1; ends early once --robots are all seen)",
    )
    parser.add_argument("--resend-s", type=float, default=2.0, help=argparse.SUPPRESS)
    parser.add_argument(
        "--check", action="store_true", help="validate the brain here first; do not send a bad one"
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    try:
        keys.validate_swarm(args.swarm)
        robots = parse_robots(args.robots) if args.robots is not None else None
        for name, v in (("--timeout-s", args.timeout_s), ("--discover-s", args.discover_s)):
            if not v > 0:
                raise InputError(f"{name} must be > 0, got {v}")
        manifest_json, data, brain_id = read_brain(args.brain, args.check)
    except (InputError, BrainError, ValueError) as e:
        print(f"patternrl swap: error: {' '.join(str(e).split())[:300]}", file=sys.stderr)
        return 2
    try:
        session = open_session_from_args(args, "tool", args.swarm)
    except ZenohSetupError as e:
        print(f"patternrl swap: error: {e}", file=sys.stderr)
        return 2
    with session:
        answers = swap_brain(
            session,
            args.swarm,
            manifest_json,
            data,
            robots,
            args.timeout_s,
            args.discover_s,
            args.resend_s,
        )
    ok = bool(answers) and all(a.answered and a.accepted for a in answers.values())
    if args.json:
        out: dict[str, Any] = {
            "swarm": args.swarm,
            "brain": args.brain,
            "brain_id": brain_id,
            "ok": ok,
            "robots": [asdict(answers[r]) for r in sorted(answers)],
        }
        print(json.dumps(out, indent=2))
    elif answers:
        print(format_table(answers, args.timeout_s))
    if not answers:
        print(f"patternrl swap: no robot of swarm '{args.swarm}' found", file=sys.stderr)
    return 0 if ok else 1
