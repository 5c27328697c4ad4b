"""Lint (issue 27): ruff over the whole checkout with the house's rules (``ruff.toml``: lines of at most 110
columns, pycodestyle, pyflakes' unused and undefined names, import order). ruff is pinned in setup.py's test
extra, so a new release cannot change the verdict on its own."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing():
    done = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", "."],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=os.environ.copy(),
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
