"""Zenoh: the session adapter (the only module of streamid that imports ``zenoh``) and the model client."""

from streamid.transport.zenoh_bus import DEFAULT_ENDPOINT, MODES, Bus, BusPublisher, ZenohSettings

__all__ = ["DEFAULT_ENDPOINT", "MODES", "Bus", "BusPublisher", "ZenohSettings"]
