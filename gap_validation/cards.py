"""Test cards as YAML (issue 25): the one writer and reader of ``gap-validate plan --out`` and the node's
``~/plan``.

The planning is :mod:`gap_validation.core.plan` (ROS-free, no YAML); the card's mapping is
:meth:`TestCard.to_dict <gap_validation.core.plan.TestCard.to_dict>` (schema: docs/PLAN.md). This module turns
it into text and back, next to :func:`gap_validation.core.config.load_config` (the house's other YAML), so the
CLI (``plan --out``) and the node (``~/plan``, the ``plan_card`` parameter) write the same document and read
it the same way.
"""
from __future__ import annotations

import os
from pathlib import Path

import yaml

from gap_validation.core.config import read_yaml
from gap_validation.core.errors import ConfigError, one_line
from gap_validation.core.plan import TestCard
from gap_validation.report.terminal import duration_text

__all__ = ["card_yaml", "card_from_document", "read_card", "CARD_VERSION"]

#: The card schema's version (``card_version``; docs/PLAN.md).
CARD_VERSION = 1


def card_yaml(card: TestCard, results_path: str | None, config_path: str | None) -> str:
    """The card's YAML document (docs/PLAN.md), with a header saying what it came from.

    Parameters
    ----------
    card : TestCard
        The card.
    results_path : str or None
        What it was planned from: the results file (the node: its live results); None for a first flight.
    config_path : str or None
        The config.
    """
    data = card.to_dict()
    data = {"card_version": data.pop("card_version"), "results": results_path, "config": config_path, **data}
    head = (f"# gap-validate plan: what to fly next ({len(card.manoeuvres)} manoeuvre(s), "
            f"{duration_text(card.flight_time_s)}); schema: docs/PLAN.md\n")
    return head + yaml.dump(data, Dumper=_CardDumper, sort_keys=False, width=120, allow_unicode=True)


class _CardDumper(yaml.SafeDumper):
    """YAML of the card: lists of numbers on one line, everything else in blocks."""


def _represent_list(dumper: yaml.SafeDumper, values: list):
    numbers = all(v is None or isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", values, flow_style=bool(values) and numbers)


_CardDumper.add_representer(list, _represent_list)


def card_from_document(data, source: str = "card") -> TestCard:
    """A card from its YAML document, or a one-line :class:`ConfigError` naming ``source`` and the bad key.

    Parameters
    ----------
    data : object
        The parsed YAML (a mapping with ``card_version`` and ``channels``).
    source : str
        The file's name (messages).
    """
    if not isinstance(data, dict) or not isinstance(data.get("channels"), dict):
        raise ConfigError(
            f"{source}: not a test card (expected a mapping with 'channels'; gap-validate plan --out "
            f"writes one)"
        )
    if data.get("card_version") != CARD_VERSION:
        raise ConfigError(f"{source}: card_version {data.get('card_version')!r}: expected {CARD_VERSION}")
    for name, channel in data["channels"].items():
        if not isinstance(channel, dict):
            raise ConfigError(f"{source}: channels.{name}: expected a mapping, got {type(channel).__name__}")
        manoeuvres = channel.get("manoeuvres") or []
        if not isinstance(manoeuvres, list):
            raise ConfigError(f"{source}: channels.{name}.manoeuvres: expected a list")
        for k, m in enumerate(manoeuvres):
            where = f"{source}: channels.{name}.manoeuvres[{k}]"
            if not isinstance(m, dict):
                raise ConfigError(f"{where}: expected a mapping")
            for key in (
                "index",
                "band_rad_s",
                "amplitude_rad",
                "duration_s",
                "repeats",
                "fade_in_s",
                "fade_out_s",
                "trim_before_s",
                "trim_between_s",
            ):
                if key not in m:
                    raise ConfigError(f"{where}: missing key {key!r}")
    try:
        card = TestCard.from_dict(data)
    except (TypeError, ValueError, KeyError, IndexError) as err:
        raise ConfigError(f"{source}: not a readable test card ({one_line(err)})") from None
    seen: dict[int, str] = {}
    for m in card.manoeuvres:
        where = f"{source}: channels.{m.channel}.manoeuvres index {m.index}"
        if m.index in seen:
            raise ConfigError(
                f"{where}: the index is also one of {seen[m.index]}'s (each manoeuvre needs its own)"
            )
        seen[m.index] = m.channel
        if len(m.band_rad_s) != 2 or not 0 < m.band_rad_s[0] < m.band_rad_s[1]:
            raise ConfigError(
                f"{where}: band_rad_s {list(m.band_rad_s)}: expected [low, high] with 0 < low < high"
            )
        if not (m.amplitude_rad > 0 and m.duration_s > 0 and m.repeats >= 1 and min(
                m.fade_in_s, m.fade_out_s, m.trim_before_s, m.trim_between_s) >= 0):
            raise ConfigError(
                f"{where}: expected amplitude_rad > 0, duration_s > 0, repeats >= 1 and fades and trims >= 0"
            )
    return card


def read_card(path: str | os.PathLike) -> tuple[TestCard, str | None, str | None]:
    """The card of a YAML file written by ``gap-validate plan --out``, or a one-line :class:`ConfigError`.

    Parameters
    ----------
    path : str or path-like
        The card file.

    Returns
    -------
    (TestCard, str or None, str or None)
        The card and what it says it was planned from (its ``results`` and ``config``).
    """
    data = read_yaml(Path(path), "card file", "card")
    card = card_from_document(data, str(path))
    return card, _text(data.get("results")), _text(data.get("config"))


def _text(value) -> str | None:
    return None if value is None else str(value)
