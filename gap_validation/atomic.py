"""Atomic file writes for the front ends (JSON, HTML report, configs, history): temporary file, then rename.

The implementation is plain Python and lives in :mod:`gap_validation.core.atomic` so that the core's
checkpoints use the very same code; this module is the front ends' name for it.
"""
from gap_validation.core.atomic import TEMP_SUFFIX, atomic_open, atomic_write_bytes, atomic_write_text

__all__ = ["atomic_open", "atomic_write_bytes", "atomic_write_text", "TEMP_SUFFIX"]
