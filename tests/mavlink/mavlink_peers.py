"""Test peers: MAVSDK's MissionRawServer as the vehicle, and a seeded lossy UDP relay."""
from __future__ import annotations

import random
import select
import socket
import threading
from dataclasses import dataclass, field


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class LossyRelay:
    """Forwards UDP datagrams between a client and a server, dropping a seeded fraction each way.

    The client sends to ``listen_port``; the relay forwards to ``server_port`` from its own
    ephemeral socket, and sends the server's replies back to the last client address seen.
    """

    def __init__(self, server_port: int, drop: float, seed: int):
        self.drop = drop
        self.rng_up = random.Random(seed)
        self.rng_down = random.Random(seed + 1)
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.listen_port = self.front.getsockname()[1]
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.server = ("127.0.0.1", server_port)
        self.client = None
        self.forwarded = [0, 0]
        self.dropped = [0, 0]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="lossy-relay")

    def start(self) -> "LossyRelay":
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.front, self.back], [], [], 0.05)
            for sock in ready:
                try:
                    data, addr = sock.recvfrom(65535)
                except OSError:
                    continue
                if sock is self.front:
                    self.client = addr
                    direction, rng, target, out = 0, self.rng_up, self.server, self.back
                else:
                    direction, rng, target, out = 1, self.rng_down, self.client, self.front
                if target is None:
                    continue
                if rng.random() < self.drop:
                    self.dropped[direction] += 1
                    continue
                self.forwarded[direction] += 1
                try:
                    out.sendto(data, target)
                except OSError:
                    pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1)
        self.front.close()
        self.back.close()


@dataclass
class MavsdkVehicle:
    """MAVSDK (C++, via the ``mavsdk`` package) as an autopilot running MissionRawServer."""

    port: int
    incoming: list = field(default_factory=list)
    cleared: list = field(default_factory=list)
    current: list = field(default_factory=list)

    def start(self) -> "MavsdkVehicle":
        from mavsdk import ComponentType, Configuration, Mavsdk
        from mavsdk.plugins.mission_raw_server import MissionRawServer

        self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.AUTOPILOT))
        result = self.mavsdk.add_any_connection(f"udpin://127.0.0.1:{self.port}")
        if int(result) != 0:
            raise RuntimeError(f"MAVSDK could not listen on UDP {self.port}: {result!r}")
        self.server_component = self.mavsdk.server_component()
        self.server = MissionRawServer(self.server_component)
        self.server.subscribe_incoming_mission(lambda res, plan, _ud: self.incoming.append((res, plan.mission_items)))
        self.server.subscribe_clear_all(lambda mission_type, _ud: self.cleared.append(mission_type))
        self.server.subscribe_current_item_changed(lambda item, _ud: self.current.append(item.seq))
        return self

    def close(self) -> None:
        self.mavsdk.destroy()
