"""Running the service: the HTTP server (uvicorn, in a thread) and the MAVLink side (link, mission
client, live loop). Used by ``gcs-pdm serve`` and by ``gcs-pdm demo``."""
from __future__ import annotations

import errno
import logging
import socket
import threading
import time

import uvicorn

from gcs_pdm.service.api import create_app
from gcs_pdm.service.config import ServiceConfig
from gcs_pdm.service.runtime import Service

log = logging.getLogger(__name__)


class StartupError(RuntimeError):
    """The service cannot start; the message says why in one line (``gcs-pdm serve`` prints it)."""


def check_http_port_free(host: str, port: int) -> None:
    """Fail before anything else is opened when the HTTP port is taken (port 0: any free port)."""
    if port == 0:
        return
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    probe = socket.socket(family, socket.SOCK_STREAM)
    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds: TIME_WAIT is no conflict
    try:
        probe.bind((host, port))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise StartupError(f"HTTP port {host}:{port} is already in use") from None
        raise StartupError(f"cannot listen for HTTP on {host}:{port}: {exc.strerror or exc}") from None
    finally:
        probe.close()


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
                self.stop()
                raise StartupError("HTTP server did not start (port in use?)")
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
    # Frames are mapped by the vehicle description's pack ids and ESC indices, and gated against what
    # its packs (with a parameter set flown over them, the paper's aircraft: that set's) can physically
    # report. Without a description no pack or motor is mapped until one is derived
    # (service/vehicle_discovery.py).
    from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping, waiting_mapping

    desc = service.vehicle
    override = service.parameter_override(desc)
    if desc is None:
        mapper = FrameMapper(waiting_mapping(), target_system=target)
    elif override is None:
        mapper = FrameMapper(frame_mapping(desc), target_system=target, envelope=envelope(desc))
    else:
        mapper = FrameMapper(target_system=target, envelope=PhysicalEnvelope.from_parameter_set(override))
    link = Link(LinkConfig(url=cfg.mavlink_url, source_system=cfg.source_system,
                           source_component=cfg.source_component, signing_key_file=cfg.signing_key_file,
                           target_system=target, tlog_path=tlog_path), mapper).start()
    if tlog_path:
        service.store.add_tlog(tlog_path, note="live session")
    loop = LiveLoop(service, link, MissionClient(link), discover=desc is None)
    service.attach_loop(loop)
    loop.start()
    if cfg.request_streams:  # ask for what the vehicle does not send (service/stream_watch.py)
        from gcs_pdm.mavlink.stream_requests import StreamPolicy
        from gcs_pdm.service.stream_watch import StreamWatch

        service.stream_watch = StreamWatch(service, link, StreamPolicy(rates_hz=cfg.stream_rates_hz)).start()
    return loop


def stop_mavlink(service: Service) -> None:
    loop = service.loop
    if loop is None:
        return
    loop.stop()
    if getattr(service, "stream_watch", None) is not None:
        service.stream_watch.stop()  # before the link closes: nothing is sent on a closed link
    loop.link.close()
    path = loop.link.config.tlog_path
    if path:
        for t in service.store.tlogs():
            if t["path"] == path:
                service.store.close_tlog(t["id"])


def serve(config: ServiceConfig, objectives: str | None = None, stop: threading.Event | None = None) -> int:
    """Run until stopped. Start-up problems raise StartupError (one line) with nothing left open."""
    from gcs_pdm.mavlink.connection import LinkError

    service = Service(config)
    http = None
    try:
        if objectives:
            try:
                service.load_objectives(objectives)
            except OSError as exc:
                raise StartupError(f"objectives file {objectives}: {exc.strerror or exc}") from None
            except ValueError as exc:
                raise StartupError(f"objectives file {objectives}: {exc}") from None
        check_http_port_free(config.http_host, config.http_port)
        try:
            start_mavlink(service)
        except LinkError as exc:
            raise StartupError(str(exc)) from None
        http = HttpServer(service, config.http_host, config.http_port).start()
    except BaseException:
        stop_mavlink(service)
        service.close()
        raise
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
