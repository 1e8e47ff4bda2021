"""The whole simulated vehicle without a socket: model + telemetry + mission server + commands.

``VehicleCore.tick()`` advances one physics step and returns the MAVLink messages the vehicle
sends in it; ``receive(msg, now)`` answers one message from a GCS. The network shell
(``gcs_pdm.sim.vehicle``) and the offline recorder (``gcs_pdm.sim.record``) both drive this, so a
recorded fixture and a live flight are built by the same code.
"""
from __future__ import annotations

from dataclasses import replace

from gcs_pdm.sim.commands import CommandHandler
from gcs_pdm.sim.mission_server import MissionServer, ServerTimeouts
from gcs_pdm.sim.model import SimConfig, TruthState, VehicleModel
from gcs_pdm.sim.telemetry import COMPONENT_ID, SYSTEM_ID, Telemetry, TelemetryConfig


def warm_up_kernel(config: SimConfig) -> None:
    """Load (or compile) the kernel's numba functions now, so the first ticks of a fast live run
    are not late: a throwaway vehicle takes off and rests."""
    model = VehicleModel(replace(config, mission=(), faults=()))
    model.step()
    model.arm()
    model._powertrain(config.physics_dt_s, 100.0, True)


class VehicleCore:
    def __init__(self, config: SimConfig, telemetry: TelemetryConfig | None = None,
                 timeouts: ServerTimeouts | None = None):
        self.config = config
        self.model = VehicleModel(config)
        self.telemetry = Telemetry(telemetry, seed=config.seed)
        self.missions = MissionServer(self.model, SYSTEM_ID, COMPONENT_ID, timeouts)
        self.commands = CommandHandler(self.model, self.telemetry, SYSTEM_ID, COMPONENT_ID)
        self.event_log: list = []
        self.last_state: TruthState = self.model.state()

    @property
    def time_s(self) -> float:
        return self.model.time_s

    def tick(self) -> list:
        events = self.model.step()
        s = self.last_state = self.model.state()
        self.event_log.extend(events)
        return self.telemetry.events(events, s) + self.telemetry.periodic(s)

    def receive(self, msg, now: float) -> list:
        out = self.missions.handle(msg, now) + self.commands.handle(msg)
        return out + self._pending_events()

    def poll(self, now: float) -> list:
        return self.missions.poll(now) + self._pending_events()

    def _pending_events(self) -> list:
        events = self.model.take_events()
        if not events:
            return []
        self.event_log.extend(events)
        self.last_state = self.model.state()
        return self.telemetry.events(events, self.last_state)
