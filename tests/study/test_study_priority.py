"""The rides' and the server's scheduling priority: what the system allows,
said as it is, and never passed on to the processes they start."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    not hasattr(os, "sched_getscheduler"), reason="Linux scheduling calls"
)

RAISE_THEN_START_A_CHILD = """
import json, os, subprocess, sys
from jaxround.study.priority import raise_priority
got = raise_priority(20)
child = subprocess.run(
    [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
    capture_output=True, text=True, check=True).stdout
print(json.dumps([got, os.sched_getscheduler(0), os.nice(0), int(child)]))
"""


def test_the_priority_is_what_the_system_allows_and_children_are_ordinary() -> None:
    # In a process of its own: a test worker must not run in real time.
    out = subprocess.run(
        [sys.executable, "-c", RAISE_THEN_START_A_CHILD],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    got, policy, nice, child_policy = json.loads(out)
    if got.startswith("SCHED_RR"):
        assert got == "SCHED_RR 20"
        assert policy == os.SCHED_RR | os.SCHED_RESET_ON_FORK
        assert child_policy == os.SCHED_OTHER
    elif got.startswith("nice"):
        assert got == f"nice {nice}" and nice <= -10 and policy == os.SCHED_OTHER
    else:
        assert got.startswith("unchanged (") and policy == os.SCHED_OTHER
        assert child_policy == os.SCHED_OTHER
