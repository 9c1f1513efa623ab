"""The tests that share a session fixture stay on one pytest-xdist worker (tests/conftest.py):
run a small suite through the project's grouping hook on two workers and look where each test
ran. (pytest 9.2 ignores the group xdist 3.8 writes into the test ids, which split the browser
tests and the Dask tests over both workers, each starting its own demo or cluster.)"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_a_group_runs_on_one_worker(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    pytester.makeini("[pytest]\nmarkers =\n    browser: drives headless Chromium\n")
    pytester.makeconftest(
        "from tests.conftest import pytest_collection_modifyitems  # noqa: F401\n"
    )
    pytester.makepyfile(
        test_browser_one="import pytest\npytestmark = pytest.mark.browser\n"
        + "".join(f"def test_b{i}(): pass\n" for i in range(4)),
        test_browser_two="import pytest\npytestmark = pytest.mark.browser\n"
        + "".join(f"def test_c{i}(): pass\n" for i in range(4)),
        test_plain="".join(f"def test_p{i}(): pass\n" for i in range(8)),
    )
    result = pytester.runpytest_subprocess(
        "-n", "2", "--dist", "loadgroup", "-v", "-p", "no:cacheprovider"
    )
    result.assert_outcomes(passed=16)
    ran = re.findall(r"\[(gw\d)\] \[ *\d+%\] PASSED (\S+)", result.stdout.str())
    assert len(ran) == 16
    browser_workers = {worker for worker, test in ran if test.startswith("test_browser")}
    assert len(browser_workers) == 1, ran
    assert {worker for worker, _ in ran} == {"gw0", "gw1"}, ran
