"""The streaming identification daemon: the adapter of :class:`~streamid.online.OnlineIdentifier` to the world.

Data flows one way: :mod:`streamid.transport.zenoh_bus` delivers payloads, the
receiving path decodes them (:mod:`streamid.wire.codec`) and pushes them into one
:class:`~streamid.online.OnlineIdentifier` per stream; closed windows are identified
off the receiving path by worker threads; models are published on Zenoh, saved to
``--state-dir`` (:mod:`streamid.daemon.state_store`) and drawn by
:mod:`streamid.viz.rerun_view`.  :mod:`streamid.daemon.config` reads the TOML file.
"""
