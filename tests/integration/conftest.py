"""The integration tests' fixtures: a stub world (:mod:`support.stub_world`) per test, and the
robot processes a test starts, stopped after it."""

from __future__ import annotations

import re
from collections.abc import Iterator

import pytest
from support.stub_world import RobotProc, StubWorld


@pytest.fixture
def world(request: pytest.FixtureRequest) -> Iterator[StubWorld]:
    name = "t" + re.sub(r"[^A-Za-z0-9_]", "_", request.node.name)[:40]
    w = StubWorld(name)
    try:
        yield w
    finally:
        w.close()


@pytest.fixture
def robots() -> Iterator[list[RobotProc]]:
    procs: list[RobotProc] = []
    try:
        yield procs
    finally:
        for p in procs:
            p.interrupt()
        for p in procs:
            try:
                p.finish(timeout=5.0)
            except AssertionError:
                p.kill()
