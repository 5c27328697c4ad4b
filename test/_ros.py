"""What the ROS tests share: a DDS domain of their own, also when pytest-xdist runs files in parallel."""
from __future__ import annotations

import contextlib
import os
import random


def domain_id() -> str:
    """A random ``ROS_DOMAIN_ID`` in this pytest worker's share of 0-101 (workers never share a domain)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    span = 102 // count
    return str((index % count) * span + random.randrange(span))


KEYS = ("ROS_PYTHON_CHECK_FIELDS", "ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")


@contextlib.contextmanager
def isolated_ros():
    """Isolated DDS traffic for the block: a domain of its own, localhost only, strict field checks (restored
    afterwards)."""
    saved = {k: os.environ.get(k) for k in KEYS}
    os.environ.update({"ROS_PYTHON_CHECK_FIELDS": "1", "ROS_DOMAIN_ID": domain_id(),
                       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
