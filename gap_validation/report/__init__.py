"""Rendering results for people: the paper's figures, the HTML report and the terminal table.

* :mod:`~gap_validation.report.figures`: the paper's figures of one channel (matplotlib, imported on first use);
* :mod:`~gap_validation.report.html`: the HTML report (Table 1, verdict, figures), ``write_report``;
* :mod:`~gap_validation.report.terminal`: the terminal table and sentences, and ``write_json``;
* :mod:`~gap_validation.report.card`: what to fly next: the bands without a verdict and the test card's manoeuvres
  that would close them (report sections, terminal lines).

Reads :mod:`gap_validation.core` results only; importing this package (or ``terminal``) imports no matplotlib.
"""
