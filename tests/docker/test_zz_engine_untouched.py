"""Runs last among the docker tests (file order): the suite removed nothing it did not make."""

import pytest

from tests.conftest import cache_record_id

pytestmark = pytest.mark.docker


def test_suite_left_a_foreign_buildkit_cache_record_alone(foreign_cache_record: str) -> None:
    assert cache_record_id(foreign_cache_record), (
        "a BuildKit cache record this suite did not create is gone: something pruned the "
        "shared engine's build cache (never `docker builder prune -a`)"
    )
