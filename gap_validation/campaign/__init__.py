"""Campaigns: many flights of many aircraft validated as Dask tasks, with fleet trends (``gap-validate
campaign``).

* :mod:`~gap_validation.campaign.manifest`: the manifest (flights: name, bag(s), config, aircraft, date,
  tags);
* :mod:`~gap_validation.campaign.fingerprint`: content hashes of a flight's bags and config (reuse results);
* :mod:`~gap_validation.campaign.task`: one flight's replay, the function a worker runs;
* :mod:`~gap_validation.campaign.runner`: the Dask orchestration (local cluster or a scheduler);
* :mod:`~gap_validation.campaign.results`: per-flight outcomes, ``campaign.json`` and ``campaign.csv``;
* :mod:`~gap_validation.campaign.findings`: the series per aircraft, channel and quantity, and trends in words
  (the statistics, regression over date and its significance, are the core's
  :mod:`~gap_validation.core.trends`);
* :mod:`~gap_validation.campaign.index`, :mod:`~gap_validation.campaign.trend_figures`: ``index.html`` and
  figures.

Nothing here is imported by the core, messages, bag, ros or report; Dask is imported only when a campaign
runs.
"""

from gap_validation.core.exports import lazy_exports

#: The package's public face: name -> the module defining it (imported when the name is first used).
_PUBLIC = {
    "run_campaign": "runner", "load_manifest": "manifest", "Manifest": "manifest", "validate_flight": "task",
    "find_trends": "findings"
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
