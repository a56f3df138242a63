"""Fixtures shared by the model unit tests."""

from __future__ import annotations

import pytest

from sim_models.sim_time import Scheduler


@pytest.fixture
def sched() -> Scheduler:
    """A fresh simulated-time scheduler at t = 0."""
    return Scheduler()
