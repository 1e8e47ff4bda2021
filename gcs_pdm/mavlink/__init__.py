"""The MAVLink shell of gcs-pdm: everything that touches the wire (docs/mavlink.md).

- ``connection``: ``LinkConfig``, ``Link`` — one pymavlink connection, one reader thread,
  frame listeners and message subscriptions, tlog recording, signing.
- ``mapping``: ``DEFAULT_MAPPING`` (data), ``FrameMapper`` — packets to ``gcs_pdm.frames``.
- ``clock``: ``VehicleClock`` — the message-time policy.
- ``tlog`` / ``replay``: ``TlogWriter``, ``scan_tlog``, ``replay_tlog`` → ``ReplaySummary``;
  ``frame_columns``: a scanned log's frames a message type at a time (the replay's mapping).
- ``mission_client``: ``MissionClient`` — upload, download, clear, set current.
- ``mission_files``: QGC WPL 110 and ``.plan`` files.

Import the submodules directly; importing this package does not import pymavlink.
"""
