"""Sources of samples: hardware adapters, and the registry that finds them by name.

Built-in sources are imported lazily (importing python-can is not free, and a
service using the serial ADC should not need it). Third-party sources register
under the ``dcobserver.sources`` entry-point group; a broken plugin is logged
and skipped, never fatal for the built-ins.
"""

from __future__ import annotations

import importlib
import logging
from importlib.metadata import entry_points

from drivers.base import CHANNELS, SampleBlock, Source, SourceClosed, SourceError, SourceHealth

__all__ = [
    "BACKENDS",
    "CHANNELS",
    "SampleBlock",
    "Source",
    "SourceClosed",
    "SourceError",
    "SourceHealth",
    "source_class",
]

log = logging.getLogger(__name__)

#: name -> (module, class). Adapters add themselves here.
BACKENDS: dict[str, tuple[str, str]] = {
    "replay": ("replay.source", "ReplaySource"),
    "serial": ("drivers.serial_adc", "SerialAdcSource"),
    "modbus": ("drivers.modbus", "ModbusSource"),
    "can": ("drivers.can_bus", "CanSource"),
}

ENTRY_POINT_GROUP = "dcobserver.sources"


def _plugins() -> dict[str, object]:
    found: dict[str, object] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            found[ep.name] = ep.load()
        except Exception as exc:  # a broken plugin must not take down the built-ins
            log.warning("ignoring source plugin %r: %s", ep.name, exc)
    return found


def source_class(name: str) -> type[Source]:
    """The source class registered as ``name``.

    Raises
    ------
    SourceError
        If no source has that name (the message lists the known ones).
    """
    if name in BACKENDS:
        module_name, class_name = BACKENDS[name]
        cls: type[Source] = getattr(importlib.import_module(module_name), class_name)
        return cls
    plugins = _plugins()
    if name in plugins:
        return plugins[name]  # type: ignore[return-value]
    known = sorted(set(BACKENDS) | set(plugins))
    raise SourceError(f"unknown source {name!r}; known sources: {', '.join(known)}")
