"""Fixtures for the station tests (helpers live in gcs_fakes.py)."""

import pytest
from gcs_fakes import FakeAutopilot

from gcs.link import StationConfig, StationLink


@pytest.fixture
def fake():
    return FakeAutopilot


@pytest.fixture
def station():
    def make(**kwargs) -> StationLink:
        now_s = kwargs.pop("now_s", 0.0)
        link_id = kwargs.pop("link_id", 0)
        # Most tests check exact command sequences: the station's own housekeeping requests
        # (HOME_POSITION) are off unless a test asks for them.
        kwargs.setdefault("request_home_position", False)
        return StationLink(StationConfig(**kwargs), link_id=link_id, now_s=now_s)

    return make
