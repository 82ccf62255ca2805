"""`make test`'s grouping (conftest.pytest_collection_modifyitems): the tests that share
a module fixture carry an xdist_group mark, and pytest-xdist's --dist loadgroup sends
each group to one worker by the name it puts after an "@" in the tests' node ids. With
pytest 9.2 the ids do not take the name (pytest-xdist issue 1386): the groups are
spread as single tests, and a module fixture is made on each worker that runs one of
its tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def shared():
    return object()


def test_a_test_that_shares_a_module_fixture_is_sent_with_its_group(request, shared):
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("runs under pytest-xdist's --dist loadgroup (make test)")
    assert request.node.nodeid.endswith(f"@{__name__}:shared"), (
        f"{request.node.nodeid}: pytest-xdist did not take the group; a module fixture is made on every worker "
        "(pytest-xdist issue 1386: pyproject.toml pins a pytest it works with)")
