"""`make test` runs `pytest -n 2 --dist loadgroup`: modules marked xdist_group share their costly
runs on one worker. Some pytest and xdist versions drop the marks silently (pytest-dev/pytest-xdist#1386)."""

import pytest

pytestmark = pytest.mark.xdist_group("grouping_check")


def test_xdist_groups_take_effect(request):
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not run under pytest-xdist --dist loadgroup")
    assert request.node.nodeid.endswith("@grouping_check"), (
        f"{request.node.nodeid}: --dist loadgroup ignored the xdist_group mark; see the pytest pin in pyproject.toml")
