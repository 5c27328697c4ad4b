"""Rendering results for people: the paper's figures, the HTML report and the terminal table.

* :mod:`~gap_validation.report.figures`: the paper's figures of one channel (matplotlib, imported on first
  use);
* :mod:`~gap_validation.report.html`: the HTML report (Table 1, verdict, figures), ``write_report``;
* :mod:`~gap_validation.report.terminal`: the terminal table and sentences, and ``write_json``;
* :mod:`~gap_validation.report.card`: what to fly next: the bands without a verdict and the test card's
  manoeuvres that would close them (report sections, terminal lines).

Reads :mod:`gap_validation.core` results only; importing this package (or ``terminal``) imports no matplotlib.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "write_report": "html", "bode_figure": "figures", "disk_figure": "figures", "write_json": "terminal",
    "table": "terminal", "foxglove_layout": "layouts", "plotjuggler_layout": "layouts"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
