import pytest

from emu_helpers import FakeGcs


@pytest.fixture
def gcs() -> FakeGcs:
    return FakeGcs()
