"""Fixtures: connected in-process Zenoh peers on free loopback ports, always closed."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
import zenoh
from hypothesis import HealthCheck, settings

from tests.helpers import loopback_endpoint, open_session

# CI (CI=true) replays the same examples every run, so a red CI is reproducible and never a
# coin toss; locally, examples are random and explore more.
settings.register_profile(
    "ci",
    max_examples=300,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "dev", max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture
def endpoint() -> str:
    """A fresh tcp/127.0.0.1:PORT endpoint."""
    return loopback_endpoint()


@pytest.fixture
def peers(endpoint: str) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """Two peers: the first listens on ``endpoint``, the second connects to it."""
    with (
        open_session(listen=[endpoint]) as first,
        open_session(connect=[endpoint]) as second,
    ):
        yield first, second
