"""Result dataclasses: what every front end (JSON, terminal table, report, diagnostics) renders.

``ValidationResult.to_json_dict()`` produces the JSON contract of DESIGN.md ("JSON results"); keys may be
added, never renamed. Non-finite numbers become ``null``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Callable

import numpy as np

from gap_validation.core.background import TrimSpectra
from gap_validation.core.manoeuvres import Manoeuvre
from gap_validation.core.margins import Margins, margins_from_epsilon, margins_note

#: Note attached to every measured nu-gap: on frequency data the winding-number condition cannot be checked.
NUGAP_DATA_NOTE = (
    "nu-gap on measured frequency points, over the measured band only, assumes the winding-number "
    "condition holds (as the paper does for rigid-body aircraft)"
)


#: The margins' keys of a channel's JSON object (:meth:`Margins.to_json_dict`).
_MARGIN_KEYS = ("gain_margin_db", "phase_margin_deg", "disk_margin")


def _num(value: Any) -> float | None:
    """A JSON-safe float: ``None`` for None, NaN and infinities."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _list(values: Any) -> list:
    """JSON-safe floats of an array, flattened (:func:`_num` of each: NaN and infinities become ``None``)."""
    if values is None:
        return []
    array = np.asarray(values, dtype=float).ravel()
    out = array.tolist()                 # Python floats, as float() of each entry gives
    if not np.isfinite(array).all():
        out = [v if math.isfinite(v) else None for v in out]
    return out


def phase_deg(response: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Unwrapped phase [deg]; with ``reference``, on the same branch as the reference's unwrapped phase
    (phase of the reference plus the unwrapped phase of response/reference), so that curves overlay.

    Parameters
    ----------
    response : array_like of complex
        A frequency response.
    reference : array_like of complex, optional
        A response whose branch the phase follows (e.g. the model's).
    """
    response = np.asarray(response, dtype=complex)
    if reference is None:
        return np.degrees(_unwrap_finite(np.angle(response)))
    reference = np.asarray(reference, dtype=complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = _unwrap_finite(np.angle(response / reference))
    return np.degrees(_unwrap_finite(np.angle(reference)) + relative)


def _unwrap_finite(angle_rad: np.ndarray) -> np.ndarray:
    """``np.unwrap`` over the finite entries only (NaN stays NaN at its own index instead of every later
    one)."""
    ok = np.isfinite(angle_rad)
    if ok.all() or angle_rad.ndim != 1:
        return np.unwrap(angle_rad)
    out = np.full(angle_rad.shape, np.nan)
    out[ok] = np.unwrap(angle_rad[ok])
    return out


def response_from_json(mag_phase: dict | None) -> np.ndarray | None:
    """A complex response from its JSON ``{magnitude_db, phase_deg}`` (the inverse of :func:`_mag_phase`; null
    entries become NaN); None for none.

    Parameters
    ----------
    mag_phase : dict or None
        A results JSON's ``measured`` or ``model`` object.
    """
    if not mag_phase or not mag_phase.get("magnitude_db"):
        return None
    mag = _array(mag_phase["magnitude_db"])
    phase = _array(mag_phase["phase_deg"])
    return 10.0 ** (mag / 20.0) * np.exp(1j * np.radians(phase))


def _array(values: Any) -> np.ndarray | None:
    """A float array from a JSON list (null -> NaN); None for a missing or empty list."""
    if not values:
        return None
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def _bode(response: np.ndarray | None, reference: np.ndarray | None = None
          ) -> tuple[np.ndarray, np.ndarray] | None:
    """Magnitude [dB] and phase [deg] (on the reference's branch) of a response; None for none or an empty
    one."""
    if response is None or len(response) == 0:
        return None
    response = np.asarray(response, dtype=complex)
    with np.errstate(divide="ignore"):
        mag = 20.0 * np.log10(np.abs(response))
    return mag, phase_deg(response, reference)


def _mag_phase(response: np.ndarray | None, reference: np.ndarray | None = None) -> dict:
    bode = _bode(response, reference)
    if bode is None:
        return {"magnitude_db": [], "phase_deg": []}
    return {"magnitude_db": _list(bode[0]), "phase_deg": _list(bode[1])}


def _curve(values: Any) -> np.ndarray | None:
    """What :func:`_list` gives, as a flat float array with NaN for its nulls; None for an empty list."""
    if values is None:
        return None
    array = np.asarray(values, dtype=float).ravel()
    if not array.size:
        return None
    return array if np.isfinite(array).all() else np.where(np.isfinite(array), array, np.nan)


class _JsonView:
    """A result dataclass that reads like its JSON object and is rebuilt from it (fields in JSON key
    order)."""

    def to_json_dict(self) -> dict:
        """The JSON object (defined by each result)."""
        raise NotImplementedError

    @classmethod
    def from_json_dict(cls, data: dict) -> Any:
        """Rebuild from the JSON object (missing keys take the defaults).

        Parameters
        ----------
        data : dict
            The object as :meth:`to_json_dict` wrote it (a ``bands`` or ``diagnosis`` entry).
        """
        return cls(**{f.name: data[f.name] for f in fields(cls) if f.name in data})

    def __getitem__(self, key: str) -> Any:
        """The value of JSON key ``key`` (KeyError for any other key)."""
        return self.to_json_dict()[key]

    def __contains__(self, key: object) -> bool:
        """Whether the JSON object has key ``key``."""
        return key in self.to_json_dict()


@dataclass(frozen=True)
class Convention:
    """A convention error named on a channel (JSON ``conventions`` entries; found by
    :func:`gap_validation.core.conventions.resolve`).

    Attributes
    ----------
    kind : str
        One of :data:`~gap_validation.core.conventions.KINDS`.
    factor : float or None
        The data are the model times this (``sign``, ``units``, ``body_frame``).
    seconds : float or None
        ``clock_offset``: how far the output leads the input [s].
    stream : str
        The stream it most likely belongs to: ``input`` or ``output`` (and the topic, in the sentence).
    fix : str
        The config change, in words (``add frame: flu to channels.pitch.output and channels.yaw.output``).
    sentence : str
        What it is and the fix, one sentence.
    changes : list of dict
        The change as data, for ``--apply-diagnosis``: ``{"channel", "stream", "key", "value"}`` (the new
        value of the stream's ``scale``, ``frame`` or ``time_offset_s``).
    """

    kind: str
    factor: float | None = None
    seconds: float | None = None
    stream: str = ""
    fix: str = ""
    sentence: str = ""
    changes: list = field(default_factory=list)

    def to_json_dict(self) -> dict:
        """The JSON object (``factor`` / ``seconds`` only where they apply)."""
        out: dict = {"kind": self.kind}
        if self.factor is not None:
            out["factor"] = float(self.factor)
        if self.seconds is not None:
            out["seconds"] = float(self.seconds)
        out.update(
            stream=self.stream, fix=self.fix, sentence=self.sentence, changes=[dict(c) for c in self.changes]
        )
        return out

    @classmethod
    def from_json_dict(cls, data: dict) -> "Convention":
        """Rebuild from :meth:`to_json_dict`.

        Parameters
        ----------
        data : dict
            A JSON ``conventions`` entry.
        """
        return cls(kind=data["kind"], factor=data.get("factor"), seconds=data.get("seconds"),
                   stream=data.get("stream", ""), fix=data.get("fix", ""), sentence=data.get("sentence", ""),
                   changes=[dict(c) for c in data.get("changes", [])])


@dataclass(frozen=True)
class Band(_JsonView):
    """A run of adjacent frequencies where epsilon(w) passes the diagnosis threshold, and why (JSON
    ``bands``).

    Attributes
    ----------
    min_rad_s, max_rad_s : float
        Edges of the band [rad/s] (grid frequencies).
    peak_rad_s : float
        Frequency of the largest epsilon(w) in the band [rad/s].
    epsilon : float
        epsilon(w) at the peak (eq. 14).
    limited_by : {"model", "data"}
        Model-limited (confident data disagree) or data-limited (low coherence, too few averages, noise).
    reason : str
        One sentence saying why.
    coherence_min : float
        Lowest coherence in the band.
    mismatch_sigma : float or None
        Largest normalised mismatch k in the band (noise scales).
    min_averages : float or None
        Fewest averages in the band.
    """

    min_rad_s: float
    max_rad_s: float
    peak_rad_s: float | None = None
    epsilon: float | None = None
    limited_by: str = "data"
    reason: str = ""
    coherence_min: float | None = None
    mismatch_sigma: float | None = None
    min_averages: float | None = None

    def contains(self, w_rad_s: float) -> bool:
        """Whether ``w_rad_s`` lies in the band (edges included).

        Parameters
        ----------
        w_rad_s : float
            A frequency [rad/s].
        """
        return self.min_rad_s <= w_rad_s <= self.max_rad_s

    def to_json_dict(self) -> dict:
        """The JSON object of DESIGN.md's ``bands`` entries (keys in this order)."""
        return {"min_rad_s": self.min_rad_s, "max_rad_s": self.max_rad_s, "peak_rad_s": self.peak_rad_s,
                "epsilon": self.epsilon, "limited_by": self.limited_by, "reason": self.reason,
                "coherence_min": self.coherence_min, "mismatch_sigma": self.mismatch_sigma,
                "min_averages": self.min_averages}


@dataclass(frozen=True)
class Candidate(_JsonView):
    """A diagnosis candidate: an effect (or pair, or refitted coefficients) and what it would leave (JSON
    ``diagnosis`` entries, best first).

    Attributes
    ----------
    effect : str
        Effect type, ``"a+b"`` for a pair (sorted names) or ``"parameter_error"``.
    parameters : dict
        Fitted parameters by name (``type.name`` when a pair repeats a name; numerator and denominator for
        ``parameter_error``).
    effects : list of dict
        The effects to append to ``model.effects`` in the config, as is (empty for ``parameter_error``).
    epsilon, nu_gap : float
        What the model with the candidate leaves on the averaged data (eqs. 13-14).
    sentence : str
        ``missing: time delay of 45 ms; adding it brings epsilon from 0.62 to 0.06``.
    improvement, epsilon_before : float
        epsilon gained, and epsilon of the current model.
    epsilon_raw : float or None
        Raw epsilon (sup over the sweeps) with the candidate.
    worst_frequency_rad_s : float
        Where the candidate's epsilon peaks [rad/s].
    complexity : int
        Fitted parameters.
    explains : bool
        The mismatch left is within the errors.
    cost, cost_before : float
        CIFER cost J with and without the candidate.
    model : dict or None
        ``parameter_error`` only: the refitted ``model`` mapping that replaces the config's.
    note : str or None
        ``parameter_error`` only: says so.
    criterion : float or None
        Its information criterion among the candidates (the diagnosis' parsimony: lower is better).
    indistinguishable_from : list of str
        The candidates the data cannot tell from this one (the top one only; it is named for having the fewest
        parameters).
    """

    effect: str
    parameters: dict = field(default_factory=dict)
    effects: list = field(default_factory=list)
    epsilon: float | None = None
    nu_gap: float | None = None
    sentence: str = ""
    improvement: float | None = None
    epsilon_before: float | None = None
    epsilon_raw: float | None = None
    worst_frequency_rad_s: float | None = None
    complexity: int = 0
    explains: bool = False
    cost: float | None = None
    cost_before: float | None = None
    model: dict | None = None
    note: str | None = None
    criterion: float | None = None
    indistinguishable_from: list = field(default_factory=list)

    def to_json_dict(self) -> dict:
        """The JSON object of DESIGN.md's ``diagnosis`` entries (``model`` and ``note`` only when
        refitted)."""
        out = {
            "effect": self.effect,
            "parameters": self.parameters,
            "effects": [dict(e) for e in self.effects],
            "epsilon": self.epsilon,
            "nu_gap": self.nu_gap,
            "sentence": self.sentence,
            "improvement": self.improvement,
            "epsilon_before": self.epsilon_before,
            "epsilon_raw": self.epsilon_raw,
            "worst_frequency_rad_s": self.worst_frequency_rad_s,
            "complexity": self.complexity,
            "explains": self.explains,
            "cost": self.cost,
            "cost_before": self.cost_before,
            "criterion": self.criterion,
            "indistinguishable_from": list(self.indistinguishable_from),
        }
        if self.model is not None:
            out["model"] = self.model
            out["note"] = self.note
        return out


def _band(value: Band | dict) -> Band:
    return value if isinstance(value, Band) else Band.from_json_dict(value)


def _candidate(value: Candidate | dict) -> Candidate:
    return value if isinstance(value, Candidate) else Candidate.from_json_dict(value)


@dataclass
class SweepResult:
    """Validation of one sweep's (raw) estimate."""

    start_s: float
    end_s: float
    epsilon: float | None
    worst_frequency_rad_s: float | None
    points_used: int

    def to_json_dict(self) -> dict:
        """The JSON object of a ``raw_sweeps`` entry (non-finite numbers are null)."""
        return {"start_s": _num(self.start_s), "end_s": _num(self.end_s), "epsilon": _num(self.epsilon),
                "worst_frequency_rad_s": _num(self.worst_frequency_rad_s), "points_used": self.points_used}

    @classmethod
    def from_json_dict(cls, data: dict) -> "SweepResult":
        """Rebuild a sweep's result from its JSON object.

        Parameters
        ----------
        data : dict
            A ``raw_sweeps`` entry of the JSON results.
        """
        return cls(_float(data.get("start_s")), _float(data.get("end_s")), data.get("epsilon"),
                   data.get("worst_frequency_rad_s"), int(data.get("points_used") or 0))


def _float(value: Any) -> float:
    return float("nan") if value is None else float(value)


def _manoeuvre_json(m: Manoeuvre, check: dict | None, samples: bool = True) -> dict:
    """A kept manoeuvre: its TIC against the model and its samples (so a report can be drawn from the
    JSON)."""
    dt = float(m.t_s[1] - m.t_s[0]) if m.t_s.size > 1 else 0.0
    out = {"kind": m.kind, "start_s": _num(m.start_s), "end_s": _num(m.end_s)}
    out.update({key: _num(value) for key, value in (check or {}).items()})
    if not samples:
        return out
    out.update(
        {
            "t0_s": _num(m.t_s[0]) if m.t_s.size else None,
            "dt_s": dt,
            "trim_samples": int(m.trim_samples),
            "input": _list(m.u),
            "output": _list(m.y),
        }
    )
    return out


def _manoeuvre_from_json(data: dict) -> Manoeuvre:
    u, y = _array(data.get("input")), _array(data.get("output"))
    n = 0 if u is None else u.size
    t = float(data.get("t0_s") or 0.0) + np.arange(n) * float(data.get("dt_s") or 0.0)
    return Manoeuvre(
        str(data.get("kind", "doublet")),
        t,
        u if u is not None else np.zeros(0),
        y if y is not None else np.zeros(0),
        _float(data.get("start_s")),
        _float(data.get("end_s")),
        int(data.get("trim_samples") or 0),
    )


@dataclass
class MimoDetail:
    """Per-element results of a MIMO channel (the ``mimo`` object of the JSON).

    Attributes
    ----------
    inputs, outputs : list of str
        Names of the inputs (columns) and outputs (rows): ``"topic field"``.
    measured, model : ndarray, (F, p, m) complex
        Measured and model response matrices.
    variance : ndarray, (F, p, m)
        Variance of each measured element.
    partial_coherence : ndarray, (F, p, m)
        Partial coherence of output i with input j given the other inputs.
    multiple_coherence : ndarray, (F, p)
        Multiple coherence of each output with all inputs.
    kappa_noise : ndarray, (F,)
        Noise scale of kappa(w) (:func:`~gap_validation.core.mimo.kappa_noise_scale`).
    worst_elements : list of dict
        Where it fails (the peak of the worst model-limited band; else where the nu-gap is attained), per
        element: ``output``, ``input``, their indices, ``kappa_alone`` (the kappa of that element's mismatch
        alone), ranked largest first.
    worst_elements_frequency_rad_s : float or None
        The frequency of ``worst_elements`` [rad/s].
    """

    inputs: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    measured: np.ndarray | None = None
    model: np.ndarray | None = None
    variance: np.ndarray | None = None
    partial_coherence: np.ndarray | None = None
    multiple_coherence: np.ndarray | None = None
    kappa_noise: np.ndarray | None = None
    worst_elements: list[dict] = field(default_factory=list)
    worst_elements_frequency_rad_s: float | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(outputs, inputs)."""
        return len(self.outputs), len(self.inputs)

    def singular_values(self, which: str = "measured") -> np.ndarray:
        """Singular values per frequency, largest first, (F, min(p, m)); NaN where not estimated.

        Parameters
        ----------
        which : {"measured", "model"}
            The matrices.
        """
        h = self.measured if which == "measured" else self.model
        out = np.full((h.shape[0], min(h.shape[1:])), np.nan)
        ok = np.all(np.isfinite(h), axis=(1, 2))
        if ok.any():
            out[ok] = np.linalg.svd(h[ok], compute_uv=False)
        return out

    def to_json_dict(self) -> dict:
        """The ``mimo`` object of a MIMO channel's JSON: per element (``elements``, row-major: output, then
        input) its measured and model magnitude and phase, partial coherence and random error; the multiple
        coherence per output; the singular values of model and data; the noise scale of kappa; the elements
        that dominate kappa at the worst frequency."""
        elements = []
        p, m = self.shape
        for i in range(p):
            for j in range(m):
                meas, model = self.measured[:, i, j], self.model[:, i, j]
                with np.errstate(divide="ignore", invalid="ignore"):
                    rel = np.sqrt(self.variance[:, i, j] / 2.0) / np.abs(meas)
                elements.append(
                    {
                        "output": self.outputs[i],
                        "input": self.inputs[j],
                        "output_index": i,
                        "input_index": j,
                        "measured": _mag_phase(meas, model),
                        "model": _mag_phase(model),
                        "partial_coherence": _list(self.partial_coherence[:, i, j]),
                        "random_error": _list(rel),
                    }
                )
        return {
            "shape": [p, m],
            "inputs": list(self.inputs),
            "outputs": list(self.outputs),
            "elements": elements,
            "multiple_coherence": [_list(self.multiple_coherence[:, i]) for i in range(p)],
            "singular_values": {
                "measured": [_list(row) for row in self.singular_values("measured").T],
                "model": [_list(row) for row in self.singular_values("model").T],
            },
            "kappa_noise": _list(self.kappa_noise),
            "worst_elements": [dict(e) for e in self.worst_elements],
            "worst_elements_frequency_rad_s": self.worst_elements_frequency_rad_s,
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> "MimoDetail":
        """Rebuild from :meth:`to_json_dict` (a report drawn from saved results).

        Parameters
        ----------
        data : dict
            The ``mimo`` object.
        """
        p, m = (int(v) for v in data.get("shape", [0, 0]))
        elements = data.get("elements") or []
        n = len(_array(data.get("kappa_noise")) if data.get("kappa_noise") else [])

        def stack(get: Callable[[dict], np.ndarray | None]) -> np.ndarray:
            out = np.full((n, p, m), np.nan, dtype=complex)
            for e in elements:
                value = get(e)
                if value is not None:
                    out[:, int(e["output_index"]), int(e["input_index"])] = value
            return out

        detail = cls(inputs=list(data.get("inputs") or []), outputs=list(data.get("outputs") or []),
                     measured=stack(lambda e: response_from_json(e.get("measured"))),
                     model=stack(lambda e: response_from_json(e.get("model"))),
                     partial_coherence=stack(lambda e: _array(e.get("partial_coherence"))).real,
                     kappa_noise=_array(data.get("kappa_noise")),
                     worst_elements=[dict(e) for e in data.get("worst_elements") or []],
                     worst_elements_frequency_rad_s=data.get("worst_elements_frequency_rad_s"))
        rel = stack(lambda e: _array(e.get("random_error"))).real
        detail.variance = 2.0 * (rel * np.abs(detail.measured)) ** 2
        rows = [_array(r) for r in data.get("multiple_coherence") or []]
        detail.multiple_coherence = np.column_stack(rows) if rows else np.zeros((n, p))
        return detail


@dataclass
class ChannelResult:
    """Model against measurement for one channel (DESIGN.md JSON keys in ``to_json_dict``)."""

    name: str
    sweeps: int = 0
    nu_gap: float | None = None
    nu_gap_frequency_rad_s: float | None = None
    epsilon: float | None = None
    worst_frequency_rad_s: float | None = None
    epsilon_raw: float | None = None
    epsilon_raw_frequency_rad_s: float | None = None
    margins: Margins = field(default_factory=lambda: margins_from_epsilon(float("nan")))
    margins_raw: Margins = field(default_factory=lambda: margins_from_epsilon(float("nan")))
    coherence_threshold: float = 0.6
    frequency_rad_s: np.ndarray | None = None
    coherence: np.ndarray | None = None
    random_error: np.ndarray | None = None
    kappa: np.ndarray | None = None
    epsilon_per_frequency: np.ndarray | None = None
    measured: np.ndarray | None = None            # complex averaged estimate
    model: np.ndarray | None = None               # complex model response
    confident: np.ndarray | None = None           # bool: coherence passes the threshold
    points_excluded: int = 0
    limited_by: str = "none"
    frequency_flags: list[str] = field(default_factory=list)
    bands: list[Band] = field(default_factory=list)
    diagnosis: list[Candidate] = field(default_factory=list)
    sweep_results: list[SweepResult] = field(default_factory=list)
    sweep_measured: list[np.ndarray] = field(default_factory=list)   # complex raw estimate per sweep (plots)
    bad_samples: dict[str, int] = field(default_factory=dict)
    epsilon_previous: float | None = None
    model_description: str = ""
    message: str = ""
    model_spec: dict = field(default_factory=dict)                   # the config's model mapping
    manoeuvres: list[Manoeuvre] = field(default_factory=list)        # doublets kept for the time domain
    time_domain: list[dict] = field(default_factory=list)            # per manoeuvre: tic, tic_input_augmented
    excitation: str | None = None                                    # kind flown (chirp, multisine, ...)
    excited_band_rad_s: tuple[float, float] | None = None            # where the flight excited the input
    # the highest frequency the channel's streams resolve (a quarter of the slowest one's rate, or up to its
    # Nyquist frequency where faster streams show its sampling): no band reaches above it; None before data
    resolved_rad_s: float | None = None
    manoeuvres_by_kind: dict[str, int] = field(default_factory=dict)  # manoeuvres that gave a response
    # every manoeuvre seen, per kind, used or not
    manoeuvres_flown: dict[str, int] = field(default_factory=dict)
    # with an airspeed stream: (V / V_trim)^2 over the flight (mean, min, max, clipped), the inputs scaled by
    # it
    dynamic_pressure_ratio: dict | None = None
    # the lead test between the manoeuvres (background.LeadTest): share, f, p_value, rows, lags_s; None before
    # enough trim
    rate_leads_surface: dict | None = None
    degrees_of_freedom: np.ndarray | None = None                     # of the noise estimate, per frequency
    # per frequency: why not confident, or None
    frequency_reasons: list = field(default_factory=list)
    # the controller check (a channel with a controller): b(P1, C) and b > nu-gap (core.robust)
    stability_margin_b: float | None = None
    stability_margin_frequency_rad_s: float | None = None
    guaranteed_stable: bool | None = None
    stability_note: str = ""
    # one-line warnings about what the numbers may not show (coupled surfaces, feedback, band edges, ...)
    warnings: list[str] = field(default_factory=list)
    # a MIMO channel (issue 14): per-element responses, coherences, singular values (MimoDetail)
    mimo: Any = None
    # why the margins from epsilon < 1 are not guaranteed (a mismatch peaking at a band edge, a failed winding
    # condition against the diagnosed model); empty: nothing known against them
    margins_caveat: str = ""
    # amplitude dependence (core.nonlinearity): the verdict, its evidence, each raw sweep's input amplitude
    nonlinearity: str | None = None
    nonlinearity_evidence: str | None = None
    input_amplitudes: list[float] = field(default_factory=list)
    # fits that sat on a search bound (never offered as a fix), said when no offered fix explains the
    # mismatch: "gain (factor at -10 (lower bound))"
    beyond_range: list[str] = field(default_factory=list)
    # within the tolerance, a difference the data resolve and one constant factor explains (ConstantFactor,
    # found by core.diagnosis.constant_factor), None otherwise
    within_tolerance: ConstantFactor | None = None
    # a sign, units, the body frame or a clock (issue 23): core.conventions.Convention, none when the config
    # is right
    conventions: list = field(default_factory=list)
    # closed loop and coupled surfaces (issue 13): per frequency, only with the config keys
    excitation_coherence: dict | None = None      # {"r_to_u": array, "r_to_y": array} with an ``excitation``
    partial_coherence: np.ndarray | None = None   # with ``other_inputs``
    # the first input's and output's spectra between the manoeuvres on the validated grid
    # (core.background.TrimSpectra: the noise a manoeuvre will meet, read by the planner); None: no trim or
    # MIMO
    trim_spectra: Any = None

    def __post_init__(self) -> None:
        # bands and candidates given as their JSON objects (hand-written results, tests) are read as such
        self.bands = [_band(b) for b in self.bands]
        self.diagnosis = [_candidate(c) for c in self.diagnosis]

    @property
    def margins_guaranteed(self) -> bool:
        """Margins exist (epsilon < 1) and nothing known says they do not hold (JSON
        ``margins_guaranteed``)."""
        return bool(self.margins.guaranteed and not self.margins_caveat)

    def margins_text(self) -> str | None:
        """Why the margins are not given or not guaranteed (JSON ``margins_note``), None when they are."""
        return margins_note(self.epsilon) or (f"margins not guaranteed: {self.margins_caveat}"
                                              if self.margins_caveat else None)

    @property
    def points_used(self) -> int:
        """Confident frequencies (those epsilon and the nu-gap are taken over)."""
        return int(np.count_nonzero(self.confident)) if self.confident is not None else 0

    def to_json_dict(self, samples: bool = True) -> dict:
        """The channel's JSON object (DESIGN.md keys first, extensions after).

        Parameters
        ----------
        samples : bool
            ``False`` leaves out the bulky parts only figures need (each raw sweep's response, the doublets'
            samples): the node's 1 Hz diagnostics read a few numbers.
        """
        head = self.headline_json_dict()
        out = {
            "nu_gap": head["nu_gap"],
            "epsilon": head["epsilon"],
            "epsilon_raw": head["epsilon_raw"],
            "worst_frequency_rad_s": head["worst_frequency_rad_s"],
            **{key: head[key] for key in _MARGIN_KEYS},
            "sweeps": head["sweeps"],
            "limited_by": head["limited_by"],
            "frequency_rad_s": _list(self.frequency_rad_s),
            "coherence": _list(self.coherence),
            "kappa": _list(self.kappa),
            "epsilon_per_frequency": _list(self.epsilon_per_frequency),
            "measured": _mag_phase(self.measured, self.model),
            "model": _mag_phase(self.model),
            "diagnosis": [c.to_json_dict() for c in self.diagnosis],
            # extensions
            "nu_gap_frequency_rad_s": head["nu_gap_frequency_rad_s"],
            "epsilon_raw_frequency_rad_s": _num(self.epsilon_raw_frequency_rad_s),
            "margins_raw": self.margins_raw.to_json_dict(),
            # why the margins are null or not guaranteed (None: they are)
            "margins_note": self.margins_text(),
            "margins_guaranteed": self.margins_guaranteed,
            "coherence_threshold": self.coherence_threshold,
            "points_used": self.points_used,
            "points_excluded": head["points_excluded"],
            "random_error": _list(self.random_error),
            "frequency_flags": list(self.frequency_flags),
            "bands": [b.to_json_dict() for b in self.bands],
            "raw_sweeps": [s.to_json_dict() for s in self.sweep_results],
            "bad_samples": dict(self.bad_samples),
            "epsilon_previous": head["epsilon_previous"],
            "model_description": self.model_description,
            "message": self.message,
            "nu_gap_note": NUGAP_DATA_NOTE,
            "model_spec": self.model_spec,
            "confident": [] if self.confident is None else [bool(c) for c in self.confident],
            "time_domain": [_manoeuvre_json(m, c, samples) for m, c in zip(self.manoeuvres, self._checks())],
            "excitation": self.excitation,
            "excited_band_rad_s": None if self.excited_band_rad_s is None else [_num(v) for v in
                                                                                 self.excited_band_rad_s],
            "resolved_rad_s": None if self.resolved_rad_s is None else _num(self.resolved_rad_s),
            "manoeuvres_by_kind": dict(self.manoeuvres_by_kind),
            "manoeuvres_flown": dict(self.manoeuvres_flown),
            "degrees_of_freedom": _list(self.degrees_of_freedom),
            "frequency_reasons": list(self.frequency_reasons),
            "warnings": list(self.warnings),
            "nonlinearity": self.nonlinearity,
            "nonlinearity_evidence": self.nonlinearity_evidence,
            "input_amplitudes": [_num(a) for a in self.input_amplitudes],
            "beyond_range": list(self.beyond_range),
            "within_tolerance": head["within_tolerance"],
            "conventions": [c.to_json_dict() for c in self.conventions],
            "dynamic_pressure_ratio": head["dynamic_pressure_ratio"],
            "rate_leads_surface": head["rate_leads_surface"],
            "trim_spectra": None if self.trim_spectra is None else self.trim_spectra.to_json_dict(),
        }
        for entry, response in zip(out["raw_sweeps"], self.sweep_measured if samples else ()):
            entry["measured"] = _mag_phase(response, self.model)
        if self.mimo is not None:               # only for a MIMO channel
            out["mimo"] = self.mimo.to_json_dict()
        if self.excitation_coherence is not None:    # only with an excitation
            out["excitation_coherence"] = {k: _list(v) for k, v in self.excitation_coherence.items()}
        if self.partial_coherence is not None:       # only with other_inputs
            out["partial_coherence"] = _list(self.partial_coherence)
        if self.stability_margin_b is not None:  # only with a controller
            out.update({"stability_margin_b": _num(self.stability_margin_b),
                        "stability_margin_frequency_rad_s": _num(self.stability_margin_frequency_rad_s),
                        "guaranteed_stable": self.guaranteed_stable, "stability_note": self.stability_note})
        return out

    def headline_json_dict(self) -> dict:
        """The few numbers of :meth:`to_json_dict` a status shows, the same values without building the
        per-frequency lists (the node's diagnostics every second): ``nu_gap``, ``epsilon``, ``epsilon_raw``,
        ``worst_frequency_rad_s``, the margins, ``sweeps``, ``limited_by``, ``points_excluded``,
        ``epsilon_previous``, ``nu_gap_frequency_rad_s``, ``within_tolerance``, ``dynamic_pressure_ratio``
        and ``rate_leads_surface``.

        Returns
        -------
        dict
        """
        return {
            "nu_gap": _num(self.nu_gap),
            "epsilon": _num(self.epsilon),
            "epsilon_raw": _num(self.epsilon_raw),
            "worst_frequency_rad_s": _num(self.worst_frequency_rad_s),
            **self.margins.to_json_dict(),
            "sweeps": int(self.sweeps),
            "limited_by": self.limited_by,
            "points_excluded": int(self.points_excluded),
            "epsilon_previous": _num(self.epsilon_previous),
            "nu_gap_frequency_rad_s": _num(self.nu_gap_frequency_rad_s),
            "within_tolerance": None if self.within_tolerance is None else {
                k: _num(v) for k, v in self.within_tolerance.to_json_dict().items()},
            "dynamic_pressure_ratio": None if self.dynamic_pressure_ratio is None else {
                k: _num(v) if k != "clipped" else int(v) for k, v in self.dynamic_pressure_ratio.items()},
            "rate_leads_surface": None if self.rate_leads_surface is None else {
                k: int(v) if k == "rows" else _num(v) for k, v in self.rate_leads_surface.items()},
        }

    def curves(self) -> dict[str, np.ndarray | None]:
        """The per-frequency curves of :meth:`to_json_dict` as flat float arrays, NaN where the JSON has null,
        None where its list is empty (the node's plot table every second, without the lists):
        ``measured_magnitude_db``, ``measured_phase_deg`` (on the model's branch), ``model_magnitude_db``,
        ``model_phase_deg``, ``coherence``, ``epsilon_per_frequency``, ``kappa`` and ``random_error``.

        Returns
        -------
        dict of str to ndarray or None
        """
        measured, model = _bode(self.measured, self.model), _bode(self.model)
        return {
            "measured_magnitude_db": None if measured is None else _curve(measured[0]),
            "measured_phase_deg": None if measured is None else _curve(measured[1]),
            "model_magnitude_db": None if model is None else _curve(model[0]),
            "model_phase_deg": None if model is None else _curve(model[1]),
            "coherence": _curve(self.coherence),
            "epsilon_per_frequency": _curve(self.epsilon_per_frequency),
            "kappa": _curve(self.kappa),
            "random_error": _curve(self.random_error),
        }

    def _checks(self) -> list[dict | None]:
        return list(self.time_domain) + [None] * (len(self.manoeuvres) - len(self.time_domain))

    @classmethod
    def from_json_dict(cls, name: str, data: dict) -> "ChannelResult":
        """Rebuild a channel's result from its JSON object (e.g. to draw a report from saved results).

        Parameters
        ----------
        name : str
            Channel name.
        data : dict
            The channel's object of the JSON results.
        """
        ch = cls(
            name=name,
            sweeps=int(data.get("sweeps") or 0),
            nu_gap=data.get("nu_gap"),
            nu_gap_frequency_rad_s=data.get("nu_gap_frequency_rad_s"),
            epsilon=data.get("epsilon"),
            worst_frequency_rad_s=data.get("worst_frequency_rad_s"),
            epsilon_raw=data.get("epsilon_raw"),
            epsilon_raw_frequency_rad_s=data.get("epsilon_raw_frequency_rad_s"),
            coherence_threshold=float(data.get("coherence_threshold", 0.6)),
            points_excluded=int(data.get("points_excluded") or 0),
            limited_by=data.get("limited_by", "none"),
            frequency_flags=list(data.get("frequency_flags") or []),
            bands=[Band.from_json_dict(b) for b in data.get("bands") or []],
            diagnosis=[Candidate.from_json_dict(c) for c in data.get("diagnosis") or []],
            bad_samples=dict(data.get("bad_samples") or {}),
            epsilon_previous=data.get("epsilon_previous"),
            model_description=data.get("model_description", ""),
            message=data.get("message", ""),
            model_spec=dict(data.get("model_spec") or {}),
            excitation=data.get("excitation"),
            manoeuvres_by_kind=dict(data.get("manoeuvres_by_kind") or {}),
            manoeuvres_flown=dict(data.get("manoeuvres_flown") or {}),
            frequency_reasons=list(data.get("frequency_reasons") or []),
            stability_margin_b=data.get("stability_margin_b"),
            stability_margin_frequency_rad_s=data.get("stability_margin_frequency_rad_s"),
            guaranteed_stable=data.get("guaranteed_stable"),
            stability_note=data.get("stability_note") or "",
            warnings=[str(w) for w in data.get("warnings") or []],
            margins_caveat=_caveat(data),
            nonlinearity=data.get("nonlinearity"),
            nonlinearity_evidence=data.get("nonlinearity_evidence"),
            input_amplitudes=[
                float(a) if a is not None else float("nan") for a in data.get("input_amplitudes") or []
            ],
            beyond_range=[str(b) for b in data.get("beyond_range") or []],
            within_tolerance=_within_tolerance(data.get("within_tolerance")),
            conventions=[Convention.from_json_dict(c) for c in data.get("conventions") or []],
            dynamic_pressure_ratio=data.get("dynamic_pressure_ratio"),
            rate_leads_surface=data.get("rate_leads_surface"),
        )
        band = data.get("excited_band_rad_s")
        ch.excited_band_rad_s = (float(band[0]), float(band[1])) if band and None not in band else None
        resolved = data.get("resolved_rad_s")
        number = isinstance(resolved, (int, float)) and not isinstance(resolved, bool)
        ch.resolved_rad_s = float(resolved) if number else None
        ch.margins = margins_from_epsilon(ch.epsilon if ch.epsilon is not None and not ch.conventions
                                          else float("nan"))
        if ch.epsilon_raw is not None:
            ch.margins_raw = margins_from_epsilon(ch.epsilon_raw)
        for key in ("frequency_rad_s", "coherence", "random_error", "kappa", "epsilon_per_frequency",
                    "degrees_of_freedom"):
            setattr(ch, key, _array(data.get(key)))
        ch.measured = response_from_json(data.get("measured"))
        ch.model = response_from_json(data.get("model"))
        if isinstance(data.get("excitation_coherence"), dict):
            ch.excitation_coherence = {k: _array(v) for k, v in data["excitation_coherence"].items()}
        if data.get("partial_coherence") is not None:
            ch.partial_coherence = _array(data.get("partial_coherence"))
        if isinstance(data.get("trim_spectra"), dict):
            ch.trim_spectra = TrimSpectra.from_json_dict(data["trim_spectra"])
        confident = data.get("confident")
        ch.confident = np.array(confident, dtype=bool) if confident else None
        raw = list(data.get("raw_sweeps") or [])
        ch.sweep_results = [SweepResult.from_json_dict(r) for r in raw]
        ch.sweep_measured = [m for m in (response_from_json(r.get("measured")) for r in raw) if m is not None]
        if data.get("mimo"):
            ch.mimo = MimoDetail.from_json_dict(data["mimo"])
        entries = list(data.get("time_domain") or [])
        ch.manoeuvres = [_manoeuvre_from_json(e) for e in entries]
        ch.time_domain = [{k: e.get(k) for k in ("tic", "tic_input_augmented")} for e in entries]
        return ch


def _caveat(data: dict) -> str:
    """The margins caveat of a channel's JSON object (its ``margins_note`` when ``margins_guaranteed`` is
    false while margins are given)."""
    note = data.get("margins_note") or ""
    prefix = "margins not guaranteed: "
    if data.get("margins_guaranteed") is False and data.get("gain_margin_db") is not None:
        return note[len(prefix):] if note.startswith(prefix) else note or "not guaranteed"
    return ""


@dataclass
class ConstantFactor:
    """A difference inside the tolerance that the data resolve and one constant complex factor explains.

    Attributes
    ----------
    gain : float
        ``|c|``: the measured response over the model's, the same at every confident frequency.
    phase_deg : float
        ``angle(c)`` [deg]; negative: the measured response lags the model's.
    error : float
        Standard error of ``c`` (relative; in rad for the phase), the systematic floor included.
    noise_scales : float
        ``|c - 1| / error``.
    min_rad_s, max_rad_s : float
        The confident frequencies it was fitted over [rad/s].
    free_play_rad : float or None
        The total free play whose describing function at the flown amplitude has this gain *and* this phase
        (within the decision's noise scales), else None. Said, never named: one amplitude cannot show
        amplitude dependence (:mod:`gap_validation.core.nonlinearity`). Found by
        :func:`gap_validation.core.diagnosis.constant_factor`.
    amplitude : float or None
        Mean input amplitude flown over those frequencies [input units].
    """

    gain: float
    phase_deg: float
    error: float
    noise_scales: float
    min_rad_s: float
    max_rad_s: float
    free_play_rad: float | None = None
    amplitude: float | None = None

    def to_json_dict(self) -> dict:
        """JSON ``within_tolerance``.

        Returns
        -------
        dict
        """
        return {"gain": self.gain, "phase_deg": self.phase_deg, "error": self.error,
                "noise_scales": self.noise_scales, "min_rad_s": self.min_rad_s, "max_rad_s": self.max_rad_s,
                "free_play_rad": self.free_play_rad, "amplitude": self.amplitude}

    @classmethod
    def from_json_dict(cls, data: dict) -> "ConstantFactor":
        """The inverse of :meth:`to_json_dict`.

        Parameters
        ----------
        data : dict
            JSON ``within_tolerance``.

        Returns
        -------
        ConstantFactor
        """
        return cls(
            **{
                k: (None if data.get(k) is None else float(data[k]))
                for k in (
                    "gain",
                    "phase_deg",
                    "error",
                    "noise_scales",
                    "min_rad_s",
                    "max_rad_s",
                    "free_play_rad",
                    "amplitude",
                )
            }
        )


def _within_tolerance(data: Any) -> ConstantFactor | None:
    """JSON ``within_tolerance`` read back (None when absent)."""
    return ConstantFactor.from_json_dict(data) if isinstance(data, dict) else None


@dataclass
class ValidationResult:
    """Results of all channels, in config order."""

    channels: dict[str, ChannelResult]
    config_source: str | None = None
    sources: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    history: dict[str, list[dict]] = field(default_factory=dict)   # per channel: epsilon per model version

    def to_json_dict(self) -> dict:
        """DESIGN.md's JSON results: ``channels`` (each :meth:`ChannelResult.to_json_dict`), config, sources,
        notes and history."""
        return {
            "channels": {name: ch.to_json_dict() for name, ch in self.channels.items()},
            "config": self.config_source,
            "sources": list(self.sources),
            "notes": list(self.notes),
            "history": {name: list(v) for name, v in self.history.items()},
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> "ValidationResult":
        """Rebuild results from :meth:`to_json_dict` output (``gap-validate report RESULTS.json``).

        Parameters
        ----------
        data : dict
            The JSON results.

        Raises
        ------
        ValueError
            When there is no ``channels`` object.
        """
        channels = data.get("channels")
        if not isinstance(channels, dict):
            raise ValueError("no 'channels' object")
        return cls(channels={name: ChannelResult.from_json_dict(name, ch) for name, ch in channels.items()},
                   config_source=data.get("config"), sources=list(data.get("sources") or []),
                   notes=list(data.get("notes") or []), history=dict(data.get("history") or {}))
