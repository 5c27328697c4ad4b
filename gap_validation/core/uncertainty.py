"""The uncertain model in the time domain: Monte Carlo of all-pass perturbations on the epsilon disk (Fig. 6).

The validation says that the aircraft ``P2`` lies, at every frequency, in the epsilon disk around the model
``P1`` (eq. 14): ``P2 = P1 (1 + d1)/(1 - d2)`` with ``|d1|, |d2| <= epsilon``. The paper checks that this
frequency-domain statement "translates appropriately into the time domain" by simulating a doublet through
500 perturbed models whose perturbations are "sampled along the boundary of the epsilon disks and realized as
all-pass transfer functions", and by drawing the tube of their responses around the model and the flight.

Realisation used here: with ``A(s)`` a stable all-pass (``|A(jw)| = 1`` for every w) and ``0 <= e < 1``,

    P2(s) = P1(s) M(s),    M(s) = (1 + e A(s)) / (1 - e A(s)).

At every frequency ``M(jw) = (1 + d)/(1 - d)`` with ``d = e A(jw)``, ``|d| = e``: the Moebius map
``d -> (1 + d)/(1 - d)`` takes the circle ``|d| = e`` onto the boundary of the epsilon disk, so
``epsilon(w) = |P2 - P1| / |P2 + P1| = |M - 1| / |M + 1| = |d| = e`` exactly (the perturbed model sits *on*
the disk boundary at every frequency, as in the paper), and ``M`` is stable by the small-gain theorem
(``|e A| = e < 1``). The phase of ``A(jw)`` turns as w rises, so each sample visits a different path around
the boundary. Samples: ``A = +1`` and ``A = -1`` first (the gain-margin markers ``(1+e)/(1-e)`` and
``(1-e)/(1+e)``: constant gain changes that bracket the nominal response), then random signs times products
of one or two first- or second-order all-pass sections whose corner frequencies are drawn log-uniformly over
the validated band.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from gap_validation.core.errors import DataError
from gap_validation.core.metrics import tic, tic_input_augmented

if TYPE_CHECKING:  # pragma: no cover
    from gap_validation.core.manoeuvres import Manoeuvre
    from gap_validation.core.models import LinearModel

__all__ = [
    "AllPassPerturbation",
    "sample_perturbations",
    "MonteCarloTube",
    "monte_carlo_tube",
    "TimeDomainCheck",
    "time_domain_check",
]


@dataclass(frozen=True)
class AllPassPerturbation:
    """One sample ``M(s) = (1 + e A(s))/(1 - e A(s))`` of the uncertain model's multiplicative factor.

    Attributes
    ----------
    epsilon : float
        Disk radius e (0 <= e < 1).
    allpass_num, allpass_den : ndarray
        ``A(s)`` (descending powers of s); ``allpass_num(s) = +-allpass_den(-s)``.
    """

    epsilon: float
    allpass_num: np.ndarray
    allpass_den: np.ndarray

    @property
    def num(self) -> np.ndarray:
        """Numerator of M(s): ``den_A + e num_A``."""
        return np.polyadd(self.allpass_den, self.epsilon * self.allpass_num)

    @property
    def den(self) -> np.ndarray:
        """Denominator of M(s): ``den_A - e num_A`` (Hurwitz for e < 1)."""
        return np.polysub(self.allpass_den, self.epsilon * self.allpass_num)

    def freqresp(self, w_rad_s: ArrayLike) -> np.ndarray:
        """M(jw).

        Parameters
        ----------
        w_rad_s : array_like
            Frequencies [rad/s].
        """
        s = 1j * np.asarray(w_rad_s, dtype=float)
        return np.polyval(self.num, s) / np.polyval(self.den, s)


def _first_order(a: float) -> tuple[np.ndarray, np.ndarray]:
    """(a - s)/(s + a): unit gain, phase 0 at DC to -180 deg at high frequency."""
    return np.array([-1.0, a]), np.array([1.0, a])


def _second_order(wn: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """(s^2 - 2 z wn s + wn^2)/(s^2 + 2 z wn s + wn^2): unit gain, phase 0 to -360 deg around wn."""
    return np.array([1.0, -2 * zeta * wn, wn * wn]), np.array([1.0, 2 * zeta * wn, wn * wn])


def sample_perturbations(epsilon: float, count: int, band_rad_s: tuple[float, float],
                         rng: np.random.Generator | int | None = 0) -> list[AllPassPerturbation]:
    """``count`` all-pass perturbations on the boundary of the epsilon disk (see the module docstring).

    Parameters
    ----------
    epsilon : float
        Disk radius, ``0 <= epsilon < 1`` (for epsilon >= 1 the uncertainty is unbounded: DataError).
    count : int
        Number of samples (>= 1); the first two are the constant factors ``A = +1`` and ``A = -1``.
    band_rad_s : (float, float)
        Frequencies [rad/s] between which the corner frequencies of the all-pass sections are drawn.
    rng : numpy Generator or int seed
        Random source (reproducible by default).
    """
    epsilon = float(epsilon)
    if not 0.0 <= epsilon < 1.0:
        raise DataError(f"Monte Carlo needs 0 <= epsilon < 1 (no bounded uncertainty), got {epsilon:g}")
    lo, hi = (float(b) for b in band_rad_s)
    if not 0.0 < lo <= hi:
        raise DataError(f"Monte Carlo band must be positive and increasing, got {band_rad_s!r}")
    rng = np.random.default_rng(rng)
    out = []
    for i in range(int(count)):
        if i < 2:
            num, den = np.array([1.0 if i == 0 else -1.0]), np.array([1.0])
        else:
            num, den = np.array([rng.choice((-1.0, 1.0))]), np.array([1.0])
            for _ in range(int(rng.integers(1, 3))):
                wn = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
                if rng.random() < 0.5:
                    n_sec, d_sec = _first_order(wn)
                else:
                    n_sec, d_sec = _second_order(wn, float(rng.uniform(0.1, 1.0)))
                num, den = np.polymul(num, n_sec), np.polymul(den, d_sec)
        out.append(AllPassPerturbation(epsilon, num, den))
    return out


@dataclass
class MonteCarloTube:
    """Responses of the uncertain model to one recorded input (paper Fig. 6).

    Attributes
    ----------
    t_s : ndarray
        Sample times [s] (uniform).
    nominal : ndarray
        Model output.
    runs : ndarray, shape (count, len(t_s))
        Output of each perturbed model (``runs[0]``, ``runs[1]``: the constant gain-margin factors).
    lower, upper : ndarray
        Envelope of the runs (the tube).
    epsilon : float
        Disk radius the perturbations were drawn with.
    """

    t_s: np.ndarray
    nominal: np.ndarray
    runs: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    epsilon: float

    def fraction_inside(self, measured: ArrayLike, tolerance: float = 0.0) -> float:
        """Fraction of the samples of ``measured`` (same times) inside the tube widened by ``tolerance``.

        Parameters
        ----------
        measured : array_like
            Measured output at the tube's times.
        tolerance : float
            Widening of the tube on both sides (output units).
        """
        measured = np.asarray(measured, dtype=float)
        inside = (measured >= self.lower - tolerance) & (measured <= self.upper + tolerance)
        return float(np.mean(inside)) if inside.size else float("nan")


def filter_uniform(num: ArrayLike, den: ArrayLike, dt_s: float, x: ArrayLike) -> np.ndarray:
    """Response of ``num/den`` (proper, stable) from rest to samples ``x`` on a uniform grid.

    Discretised exactly for a piecewise-linear input (first-order hold, as ``scipy.signal.lsim``).

    Parameters
    ----------
    num, den : array_like
        Transfer function coefficients (descending powers of s).
    dt_s : float
        Sample step [s].
    x : array_like
        Input samples.
    """
    from scipy import signal  # here: scipy.signal is slow to import and most runs never come here

    bd, ad, _ = signal.cont2discrete((np.atleast_1d(num), np.atleast_1d(den)), dt_s, method="foh")
    return signal.lfilter(np.ravel(bd), np.ravel(ad), x)


def monte_carlo_tube(model: LinearModel, epsilon: float, t_s: ArrayLike, u: ArrayLike, *, count: int = 500,
                     band_rad_s: tuple[float, float] | None = None,
                     rng: np.random.Generator | int | None = 0) -> MonteCarloTube:
    """Simulate the model and ``count`` perturbed models (on the epsilon-disk boundary) for input ``u``.

    Parameters
    ----------
    model : LinearModel
        The nominal model P1 (any :class:`~gap_validation.core.models.LinearModel`, delays included).
    epsilon : float
        Averaged-data epsilon of the channel (the paper uses the averaged disks), ``< 1``.
    t_s, u : array_like
        Uniformly sampled time [s] and input (deviation from trim, starting at rest).
    count : int
        Number of Monte Carlo runs (the paper: 500).
    band_rad_s : (float, float), optional
        Band for the all-pass corner frequencies (default 0.5 to 100 rad/s).
    rng : numpy Generator or int seed
        Random source (reproducible by default).

    Returns
    -------
    MonteCarloTube
    """
    t = np.asarray(t_s, dtype=float).ravel()
    u = np.asarray(u, dtype=float).ravel()
    t = t - t[0] if t.size else t                 # epoch stamps: steps are uniform only relative to the start
    if t.size < 3 or t.shape != u.shape:
        raise DataError(f"Monte Carlo needs matching time and input samples (got {t.size} and {u.size})")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if not dt > 0 or np.max(np.abs(steps - dt)) > 1e-3 * dt:
        raise DataError("Monte Carlo needs uniformly sampled input")
    nominal = model.simulate(t, u)
    samples = sample_perturbations(epsilon, count, band_rad_s or (0.5, 100.0), rng)
    runs = np.empty((len(samples), t.size))
    for i, p in enumerate(samples):
        runs[i] = filter_uniform(p.num, p.den, dt, nominal)
    return MonteCarloTube(
        np.asarray(t_s, dtype=float).ravel(),
        nominal,
        runs,
        runs.min(axis=0),
        runs.max(axis=0),
        float(epsilon),
    )


@dataclass(frozen=True)
class TimeDomainCheck:
    """Model against flight on one manoeuvre (paper eqs. 1 and 3), deviations from trim.

    Attributes
    ----------
    t_s, u, y_flight, y_model : ndarray
        Times [s], input and outputs about trim (the model starts at rest at the first sample).
    tic, tic_input_augmented : float
        Theil inequality coefficient of model and flight output (eq. 1) and of the input-output pairs (eq. 3):
        0 for identical signals, 1 at worst.
    """

    t_s: np.ndarray
    u: np.ndarray
    y_flight: np.ndarray
    y_model: np.ndarray
    tic: float
    tic_input_augmented: float


def time_domain_check(model: LinearModel, manoeuvre: Manoeuvre) -> TimeDomainCheck:
    """Simulate ``model`` for a recorded manoeuvre's input and compare with the flight output (TIC).

    Parameters
    ----------
    model : LinearModel
        The channel's model (effects and delays included).
    manoeuvre : Manoeuvre
        From :class:`~gap_validation.core.manoeuvres.ManoeuvreRecorder` (aligned, uniform samples).
    """
    u, y = manoeuvre.deviations()
    n = manoeuvre.t_s.size
    step = (manoeuvre.t_s[-1] - manoeuvre.t_s[0]) / max(n - 1, 1)
    y_model = model.simulate(np.arange(n) * step, u)      # on the grid: uniform (epoch stamps round off)
    return TimeDomainCheck(manoeuvre.t_s, u, y, y_model, tic(y_model, y), tic_input_augmented(y_model, y, u))
