"""What the parity tests share: where two JSON trees differ."""
from __future__ import annotations

import math


def json_differences(a, b, where: str = "", rel: float = 1e-9, abs_tol: float = 1e-12) -> list[str]:
    """Where two JSON trees differ: keys, lengths, values (numbers to ``rel``, NaN equal to NaN)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [
            f"{where}.{k}: only in {'the first' if k in a else 'the second'}" for k in sorted(set(a) ^ set(b))
        ]
        return out + [
            d for k in a if k in b for d in json_differences(a[k], b[k], f"{where}.{k}", rel, abs_tol)
        ]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} != {len(b)} items"]
        return [
            d
            for i, (x, y) in enumerate(zip(a, b))
            for d in json_differences(x, y, f"{where}[{i}]", rel, abs_tol)
        ]
    if (
        isinstance(a, float)
        and isinstance(b, (int, float))
        or isinstance(b, float)
        and isinstance(a, (int, float))
    ):
        if math.isnan(a) and math.isnan(b) or math.isclose(a, b, rel_tol=rel, abs_tol=abs_tol):
            return []
        return [f"{where}: {a!r} != {b!r}"]
    return [] if a == b else [f"{where}: {a!r} != {b!r}"]
