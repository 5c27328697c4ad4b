"""What the ROS tests share: a DDS domain of their own, also when pytest-xdist runs files in parallel."""
from __future__ import annotations

import os
import random


def domain_id() -> str:
    """A random ``ROS_DOMAIN_ID`` in this pytest worker's share of 0-101 (workers never share a domain)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    span = 102 // count
    return str((index % count) * span + random.randrange(span))
