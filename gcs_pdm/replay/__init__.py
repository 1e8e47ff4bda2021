"""Replaying a recorded flight (tlog, DataFlash ``.bin``, ULog ``.ulg``) through the core: which
vehicle it diagnoses, the traced estimator/diagnoser pipeline, the ``gcs-pdm replay`` command and
the SoC-calibration evaluation over recorded logs. Above the readers (``mavlink``, ``logs``) and
the core (``estimation``, ``diagnosis``) it drives."""
