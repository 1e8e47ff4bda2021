"""gcs-pdm: prognostic decision making beside a MAVLink ground station."""

__version__ = "0.1.0"
