"""The verdicts in words live in one module (issue 27): :mod:`gap_validation.core.wording` says what the
statistics, the fits, the ranking, the convention and amplitude checks decided, from plain values, and no
other module words a verdict."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from gap_validation.core import wording
from gap_validation.core.results import Band, Candidate, ConstantFactor

PACKAGE = Path(wording.__file__).resolve().parents[1]

#: Phrases only a verdict sentence has. Each was in another module before issue 27 (diagnosis, mimo, the
#: report, the node's status, ``--apply-diagnosis``).
VERDICT_PHRASES = (
    "-limited at",
    "fly better sweeps",
    "noise scales left",
    "which explains the mismatch",
    "Model-limited",
    "Data-limited",
    "beyond the search range (not offered",
    "fail the winding-number condition",
    "no confident frequency:",
    "confident data disagree with the model",
    "the random error explains the mismatch",
    "may continue outside",
    "dominates (its mismatch alone",
    "epsilon would be",
    "which no airframe",
    "disagree beyond their errors at",
    "agree within their errors (",
    "is mounted reversed",
    "is logged in",
    "with the opposite sign:",
)


def _strings(tree: ast.AST) -> list[tuple[int, str]]:
    """Every string literal and f-string part of a module, docstrings left out."""
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
    ]


def _offenders(root: Path) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "wording.py":
            continue
        for line, text in _strings(ast.parse(path.read_text(encoding="utf-8"))):
            found += [
                f"{path.relative_to(root.parent)}:{line}: {phrase!r}"
                for phrase in VERDICT_PHRASES
                if phrase in text
            ]
    return found


def test_no_other_module_words_a_verdict():
    assert not _offenders(PACKAGE)


def test_the_check_finds_a_verdict_worded_elsewhere(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "wording.py").write_text('A = "model-limited at 4 rad/s"\n')
    (pkg / "report.py").write_text(
        '"""Model-limited in a docstring is prose."""\ndef f(x):\n    return f"data-limited at {x} rad/s"\n'
    )
    assert _offenders(pkg) == ["pkg/report.py:3: '-limited at'"]


def test_wording_reads_no_statistics_fit_or_estimate():
    tree = ast.parse(Path(wording.__file__).read_text(encoding="utf-8"))
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {
        alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names
    }
    assert imported <= {
        "__future__",
        "math",
        "typing",
        "gap_validation.core.effects",
        "gap_validation.core.results",
    }


def _band(limited_by, lo, hi, eps, reason="why"):
    return Band(min_rad_s=lo, max_rad_s=hi, peak_rad_s=hi, epsilon=eps, limited_by=limited_by, reason=reason)


def test_the_message_leads_with_the_worst_model_limited_band_and_counts_what_was_left_out():
    bands = [_band("data", 1.0, 2.0, 0.9), _band("model", 10.0, 20.0, 0.3), _band("model", 30.0, 30.0, 0.5)]
    text = wording.channel_message(
        "pitch",
        bands=bands,
        epsilon=0.5,
        worst_rad_s=30.0,
        epsilon_threshold=0.15,
        top_sentence="missing: x",
        beyond_range=[],
        within_tolerance=None,
        frequencies=40,
        not_excited=2,
        low_coherence=0,
        few_dof=3,
        coherence_threshold=0.6,
        min_dof=10,
    )
    assert text == (
        "pitch: model-limited at 30 rad/s: epsilon 0.50 at 30 rad/s is well outside the random error; "
        "also data-limited at 1-2 rad/s, model-limited at 10-20 rad/s; missing: x "
        "(5 of 40 frequencies excluded: 2 not excited, 3 with fewer than 10 degrees of freedom)"
    )


def test_a_fit_within_the_tolerance_says_the_constant_factor():
    found = ConstantFactor(
        gain=0.92, phase_deg=-10.0, error=0.01, noise_scales=17.0, min_rad_s=1.36, max_rad_s=44.0
    )
    text = wording.channel_message(
        "",
        bands=[],
        epsilon=0.1,
        worst_rad_s=5.0,
        epsilon_threshold=0.15,
        top_sentence=None,
        beyond_range=[],
        within_tolerance=found,
        frequencies=40,
        not_excited=0,
        low_coherence=0,
        few_dof=0,
        coherence_threshold=0.6,
        min_dof=10,
    )
    assert text.startswith(
        "model fits: epsilon 0.10 at 5 rad/s, within 0.15 at every confident frequency; "
        "within the tolerance, the data still resolve a constant factor (17 noise scales)"
    )
    assert "10 deg behind" in text and "(1.36-44 rad/s, +-0.01)" in text


@pytest.mark.parametrize(
    "max_dof, max_coherence, why",
    [
        (6.0, 0.9, "too few degrees of freedom (at most 6 < 10)"),
        (None, 0.42, "coherence below 0.6 everywhere (at most 0.42)"),
        (None, None, "nothing estimated"),
    ],
)
def test_no_confident_frequency_says_what_to_fly(max_dof, max_coherence, why):
    text = wording.no_confident_sentence(
        "roll", coherence_threshold=0.6, min_dof=10, max_dof=max_dof, max_coherence=max_coherence
    )
    assert text.startswith(f"roll: data-limited: no confident frequency: {why}")


def test_apply_diagnosis_reasons():
    reason = wording.no_fix_reason
    assert reason("model", epsilon=0.4, candidates=False, best_epsilon=None).startswith(
        "model-limited, but no"
    )
    assert reason("data", epsilon=0.4, candidates=False, best_epsilon=None).startswith("data-limited: fly")
    assert (
        reason("none", epsilon=None, candidates=False, best_epsilon=None)
        == "nothing validated (no confident frequency)"
    )
    assert (
        reason("none", epsilon=0.08, candidates=False, best_epsilon=None)
        == "the model fits (epsilon 0.08): nothing to fix"
    )
    assert (
        reason("none", epsilon=0.08, candidates=True, best_epsilon=0.05)
        == "the channel is not model-limited (limited by none)"
    )
    assert reason("model", epsilon=0.4, candidates=True, best_epsilon=0.3).endswith(
        "(none leaves the data within their errors; the best leaves epsilon 0.30)"
    )


def test_report_tail_and_status_line():
    assert (
        wording.limited_sentence("model", "missing: x")
        == " Model-limited; the likeliest missing effect: missing: x."
    )
    assert wording.limited_sentence("model", "missing: x", likeliest=False) == " Model-limited; missing: x."
    assert wording.limited_sentence("none", None) == ""
    assert (
        wording.candidate_line(
            Candidate(effect="time_delay", effects=[{"type": "time_delay", "seconds": 0.045}], epsilon=0.06)
        )
        == "missing: time delay of 45 ms (epsilon would be 0.06)"
    )
    assert wording.candidate_line(None) == ""


def test_mimo_message():
    assert wording.mimo_message(nu_gap=None, limited_by="data", bands=[], kappa_threshold=0.15).startswith(
        "no confident frequency"
    )
    band = _band("model", 4.0, 12.0, 0.4, reason="kappa 0.40 at 12 rad/s is 9.0 noise scales from the data")
    text = wording.mimo_message(
        nu_gap=0.4,
        limited_by="model",
        bands=[band],
        kappa_threshold=0.15,
        element={"input": "aileron", "output": "p", "kappa_alone": 0.38},
        element_rad_s=12.0,
        kappa_all=0.4,
        top_sentence=None,
    )
    assert text == (
        "model-limited at 4-12 rad/s: kappa 0.40 at 12 rad/s is 9.0 noise scales from the data; at 12 "
        "rad/s the element aileron -> p dominates (its mismatch alone would give kappa 0.38; all "
        "together 0.40); no column effect explains it"
    )
