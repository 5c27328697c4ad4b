"""Stability margins that a controller designed on the model needs, from epsilon (paper eqs. 15-17).

If the measured (true) response lies in the epsilon disk around the model, ``P2 = P1 (1 + d1)/(1 - d2)`` with
``|d1|, |d2| <= epsilon < 1`` (eq. 14), a controller with at least these classical margins on the model is
guaranteed to stabilise the real aircraft. For epsilon >= 1 nothing is guaranteed: every margin is ``None``
and no number is ever printed for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Margins", "margins_from_epsilon", "margins_note", "STANDARD_EPSILON", "WARN_EPSILON",
           "STANDARD_MARGINS"]

#: epsilon of the paper's "standard stability margins of a 6 dB gain margin and a 45 deg phase margin"
#: (Section III, eqs. 15-16: 2 asin(0.38) = 44.7 deg): below it a controller with standard margins on the
#: model is guaranteed stable on the aircraft. The node's ERROR level, the figures' and the report's standard
#: line.
STANDARD_EPSILON = 0.38
#: epsilon of the warning level (eqs. 15-16: 4.4 dB, 29 deg guaranteed), before :data:`STANDARD_EPSILON` is
#: reached.
WARN_EPSILON = 0.25
#: The traditional Nichols exclusion region the standard margins draw: gain [dB] and phase [deg] margins.
STANDARD_MARGINS = (6.0, 45.0)


@dataclass(frozen=True)
class Margins:
    """Margins required of a controller, from the overbounding-disk radius epsilon.

    Attributes
    ----------
    gain_margin_db : float or None
        ``20 log10((1 + e)/(1 - e))`` [dB] (eq. 15).
    phase_margin_deg : float or None
        ``2 asin(e)`` [deg] (eq. 16).
    disk_margin : float or None
        ``2 e / (1 - e^2)`` (eq. 17), the radius of the epsilon disk of the relative perturbation.
    lower_disk_marker : float or None
        ``(1 - e)/(1 + e)``: where the disk crosses the real axis on the left (paper: 0.75).
    upper_disk_marker : float or None
        ``(1 + e)/(1 - e)``: where it crosses on the right (paper: 1.33).
    epsilon : float or None
        The epsilon the margins were computed from (None when not finite).

    All are None when epsilon >= 1 or not finite: no guarantee.
    """

    gain_margin_db: float | None
    phase_margin_deg: float | None
    disk_margin: float | None
    lower_disk_marker: float | None = None
    upper_disk_marker: float | None = None
    epsilon: float | None = None

    @property
    def guaranteed(self) -> bool:
        """True when margins exist (epsilon < 1)."""
        return self.gain_margin_db is not None

    def to_json_dict(self) -> dict:
        """JSON keys of DESIGN.md: ``gain_margin_db``, ``phase_margin_deg``, ``disk_margin`` (None ->
        null)."""
        return {key: getattr(self, key) for key in ("gain_margin_db", "phase_margin_deg", "disk_margin")}


def margins_note(eps: float | None) -> str | None:
    """Why no margins are given for ``eps`` (one line), or None when they are (``0 <= eps < 1``).

    Parameters
    ----------
    eps : float or None
        epsilon (None or NaN: no frequency passed the coherence threshold).

    Examples
    --------
    >>> margins_note(1.2)
    'epsilon 1.2 >= 1: the disk around the model contains -P (eq. 14), no stability guarantee, margins not
    given'
    """
    if eps is None or (isinstance(eps, float) and math.isnan(eps)):
        return "no epsilon (no frequency passed the coherence threshold): margins not given"
    eps = float(eps)
    if math.isinf(eps):
        return "epsilon is infinite (P2 = -P1 at some frequency): no stability guarantee, margins not given"
    if eps >= 1.0:
        return (f"epsilon {eps:.3g} >= 1: the disk around the model contains -P (eq. 14), no stability "
                "guarantee, margins not given")
    if eps < 0.0:
        return f"epsilon {eps:.3g} is negative: margins not given"
    return None


def margins_from_epsilon(eps: float | None) -> Margins:
    """Gain, phase and disk margins guaranteed by an epsilon-disk validation (paper eqs. 15-17).

    Parameters
    ----------
    eps : float
        Overbounding-disk radius epsilon (sup over frequency of eq. 14's per-frequency radius).

    Returns
    -------
    Margins
        All fields None when ``eps`` is >= 1, negative, NaN or infinite (no guarantee). ``eps = 0.1404``
        (paper example) gives 2.45 dB, 16.1 deg, disk margin 0.286, markers 0.754 and 1.33.

    Examples
    --------
    The paper's pitch channel (epsilon 0.1404):

    >>> m = margins_from_epsilon(0.1404)
    >>> print(f"{m.gain_margin_db:.3f} dB, {m.phase_margin_deg:.1f} deg, disk {m.disk_margin:.3f}")
    2.455 dB, 16.1 deg, disk 0.286
    >>> margins_from_epsilon(1.2).gain_margin_db is None     # no guarantee beyond epsilon 1
    True
    """
    if eps is None:
        return Margins(None, None, None)
    eps = float(eps)
    if not math.isfinite(eps) or eps < 0.0 or eps >= 1.0:
        return Margins(None, None, None, epsilon=eps if math.isfinite(eps) else None)
    upper = (1.0 + eps) / (1.0 - eps)
    return Margins(
        gain_margin_db=20.0 * math.log10(upper),
        phase_margin_deg=math.degrees(2.0 * math.asin(eps)),
        disk_margin=2.0 * eps / (1.0 - eps * eps),
        lower_disk_marker=1.0 / upper,
        upper_disk_marker=upper,
        epsilon=eps,
    )
