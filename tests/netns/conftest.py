"""The ``net`` fixture: namespaces, links and processes of one test, removed whatever happens."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from netns_hosts import Net, require_network_tools


@pytest.fixture
def net(tmp_path: Path) -> Iterator[Net]:
    require_network_tools()
    n = Net(tmp_path)
    try:
        yield n
    finally:
        n.close()
