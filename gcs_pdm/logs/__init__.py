"""Flight logs users already have, from the autopilot itself: ArduPilot DataFlash ``.bin``
(:mod:`.dataflash`) and PX4 ULog ``.ulg`` (:mod:`.ulog`), read into :class:`.series.LogSeries` and
from there into the fitter's flight tables and the telemetry frames. docs/fitting.md, "Log formats"."""
