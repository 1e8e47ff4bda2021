"""Running the service: the HTTP server (uvicorn, in a thread) and the MAVLink side (link, mission
client, live loop). Used by ``gcs-pdm serve`` and by ``gcs-pdm demo``."""
from __future__ import annotations

import logging
import threading
import time

import uvicorn

from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import ServiceConfig
from gcs_pdm.service.runtime import Service

log = logging.getLogger(__name__)


class HttpServer:
    """uvicorn on a background thread, stoppable; port 0 picks a free port."""

    def __init__(self, service: Service, host: str, port: int):
        self.app = create_app(service)
        self.server = uvicorn.Server(uvicorn.Config(self.app, host=host, port=port, log_level="warning",
                                                    lifespan="off", access_log=False))
        self.thread = threading.Thread(target=self.server.run, name="http", daemon=True)

    def start(self, timeout: float = 10.0) -> "HttpServer":
        self.thread.start()
        deadline = time.monotonic() + timeout
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("HTTP server did not start (port in use?)")
            time.sleep(0.02)
        return self

    @property
    def url(self) -> str:
        sock = self.server.servers[0].sockets[0]
        host, port = sock.getsockname()[:2]
        return f"http://{host}:{port}"

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=5.0)


def start_mavlink(service: Service):
    """Open the link, start the live loop; returns the loop (``service.loop``)."""
    from gcs_pdm.mavlink.connection import Link, LinkConfig
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.mission_client import MissionClient
    from gcs_pdm.mavlink.plausibility import PhysicalEnvelope
    from gcs_pdm.service.live import LiveLoop

    cfg = service.config
    tlog_path = None
    if cfg.record_tlog:
        folder = cfg.data_path / "tlogs"
        folder.mkdir(parents=True, exist_ok=True)
        tlog_path = str(folder / time.strftime("live_%Y%m%dT%H%M%S.tlog"))
    target = None if cfg.target_system == "auto" else cfg.target_system
    # Frames are gated against what the active parameter set's packs can physically report.
    mapper = FrameMapper(target_system=target, envelope=PhysicalEnvelope.from_parameter_set(service.params))
    link = Link(LinkConfig(url=cfg.mavlink_url, source_system=cfg.source_system,
                           source_component=cfg.source_component, signing_key_file=cfg.signing_key_file,
                           target_system=target, tlog_path=tlog_path), mapper).start()
    if tlog_path:
        service.store.add_tlog(tlog_path, note="live session")
    loop = LiveLoop(service, link, MissionClient(link))
    service.attach_loop(loop)
    loop.start()
    return loop


def stop_mavlink(service: Service) -> None:
    loop = service.loop
    if loop is None:
        return
    loop.stop()
    loop.link.close()
    path = loop.link.config.tlog_path
    if path:
        for t in service.store.tlogs():
            if t["path"] == path:
                service.store.close_tlog(t["id"])


def serve(config: ServiceConfig, objectives: str | None = None, stop: threading.Event | None = None) -> int:
    service = Service(config)
    if objectives:
        service.load_objectives(objectives)
    start_mavlink(service)
    http = HttpServer(service, config.http_host, config.http_port).start()
    log.info("HTTP API on %s (docs at /docs), MAVLink on %s, policy %s", http.url, config.mavlink_url, service.policy)
    stop = stop or threading.Event()
    if threading.current_thread() is threading.main_thread():
        import signal

        # systemd and docker stop with SIGTERM: close the link, the tlog and the database cleanly.
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        log.info("stopping")
    finally:
        stop_mavlink(service)
        http.stop()
        service.close()
    return 0
