"""``gcs-pdm replay FILE``: replay a tlog through the frame mapping and print a summary."""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from gcs_pdm.logs.kind import NOT_A_LOG
from gcs_pdm.mavlink.mapping import FrameMapper, MappingError
from gcs_pdm.process_gc import start_up_over


#: a log up to this size replays interpreted on a cold cache sooner than compiling takes (about 35 s
#: of wall on 2 cores): interpreted costs ~2 ms of CPU more per second of a tlog (320 B/s), ~30 ms
#: per second of a DataFlash log (10 kB/s): break-even near 6-12 MB (docs/notes/2026-11-27-cold-start.md)
INTERPRET_UP_TO_BYTES = 8_000_000


def register(subparsers) -> None:
    p = subparsers.add_parser("replay")
    p.add_argument("file", type=Path, help="tlog file (8-byte big-endian µs timestamp + packet records)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--speed", type=float, default=None, help="pace at this multiple of real time (default: as fast as possible)")
    p.add_argument("--udp", metavar="HOST:PORT", default=None, help="also re-send every valid packet to this UDP address")
    p.add_argument("--mapping", type=Path, default=None, help="JSON file with a message->frame mapping (default: built-in)")
    p.add_argument("--system", type=int, default=None, help="vehicle system id (default: first autopilot heartbeat)")
    p.add_argument("--component", type=int, default=None, help="vehicle component id (default: first autopilot heartbeat)")
    p.add_argument("--no-diagnose", action="store_true", help="skip the estimator/diagnoser (gcs_pdm.diagnosis)")
    p.add_argument("--vehicle", default=None, metavar="FILE|PRESET",
                   help="the vehicle description to diagnose (docs/vehicles.md); default: a provisional one "
                        "derived from the log, as `gcs-pdm vehicle init --from LOG` writes it")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gcs_pdm.mavlink.replay import replay_tlog

    if not args.file.is_file():
        print(f"gcs-pdm replay: error: no such file: {args.file}", file=sys.stderr)
        return 2
    if args.file.suffix.lower() in (".bin", ".ulg"):  # a tlog that is none is said below, with its summary
        from gcs_pdm.logs.kind import NotALog, log_kind

        try:
            log_kind(args.file)
        except (NotALog, OSError) as exc:
            print(f"gcs-pdm replay: error: {exc}", file=sys.stderr)
            return 2
    if not args.no_diagnose:  # a cold cache: this run interpreted while the models compile for the next
        from gcs_pdm.compiled import interpret_while_cold

        interpret_while_cold("gcs_pdm.replay.warm_up:REPLAY_GROUPS",
                             lambda line: print(f"gcs-pdm replay: {line}", file=sys.stderr, flush=True),
                             getattr(args, "process_argv", None),
                             interpreting_pays=args.file.stat().st_size <= INTERPRET_UP_TO_BYTES)
    consumer = desc = None
    if not args.no_diagnose or args.vehicle:  # a given vehicle names the packs even undiagnosed
        from gcs_pdm.vehicle.description import VehicleError
        from gcs_pdm.replay.vehicle import TracedPipeline, replay_vehicle

        try:
            desc, about = replay_vehicle(args.file, args.vehicle)
        except VehicleError as exc:
            print(f"gcs-pdm replay: error: --vehicle: {exc}", file=sys.stderr)
            return 2
    if desc is None:  # none given, none derived (or not asked for): the paper's aircraft
        from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

        if not args.no_diagnose:
            logging.getLogger(__name__).warning("replay: %s; diagnosing as the paper's aircraft (edge540): "
                                                "give --vehicle", about["why"])
        desc = PRESETS[DEFAULT_PRESET]
    if not args.no_diagnose:
        # The estimator/diagnoser consume the frames; faults and the sampled estimate land in the summary.
        consumer = TracedPipeline(desc, about)
    try:
        mapping = json.loads(args.mapping.read_text()) if args.mapping else None
        if mapping is None:
            from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping

            mapper = FrameMapper(frame_mapping(desc), target_system=args.system, target_component=args.component,
                                 envelope=envelope(desc))
        else:
            mapper = FrameMapper(mapping, target_system=args.system, target_component=args.component)
    except (OSError, ValueError, MappingError) as exc:
        print(f"gcs-pdm replay: error: bad mapping: {exc}", file=sys.stderr)
        return 2
    start_up_over()
    try:
        if args.file.suffix.lower() in (".bin", ".ulg"):  # an autopilot's own log: gcs_pdm.logs
            return _print_log_replay(args.file, desc, consumer, as_json=args.json)
        summary = replay_tlog(args.file, mapper=mapper, speed=args.speed, udp_target=args.udp,
                              frame_consumer=consumer).to_dict()
    finally:  # the trace's worker thread ends with the replay, however it ends
        if consumer is not None:
            consumer.close()
    from gcs_pdm.replay.vehicle import print_estimate

    # 2: nothing could be read; 1: read, but neither packs nor motors could be diagnosed.
    diagnosable = summary["frames_by_kind"].get("pack") or summary["frames_by_kind"].get("motor")
    status = 2 if not summary["readable"] else (0 if diagnosable else 1)
    if args.json:
        print(json.dumps(summary))
        return status
    if not summary["readable"]:
        print(f"gcs-pdm replay: error: {args.file}: {NOT_A_LOG} ({summary['not_diagnosed'][0].removeprefix('nothing: ')})",
              file=sys.stderr)
        return status
    print(f"{summary['path']}: {summary['messages']} messages, {summary['frames']} frames "
          f"in {summary['elapsed_s']:.3f} s ({summary['messages_per_s']} msg/s, frame consumer included)")
    print(f"  tlog: start {summary['tlog_start_utc']}, {summary['tlog_duration_s']} s; "
          f"frame time span {summary['frame_time_span_s']}")
    print(f"  vehicle: {summary['vehicle']}")
    print(f"  skipped: {summary['skipped']}; other sources {summary['mapping']['other_source']}, "
          f"before vehicle identified {summary['mapping']['before_vehicle']}")
    print("  frames by kind: " + ", ".join(f"{k}={v}" for k, v in summary["frames_by_kind"].items()))
    print("  messages by type:")
    for name, count in summary["messages_by_type"].items():
        print(f"    {name:<28} {count}")
    print(f"  time: {summary['mapping']['time_rejected']} messages with a rejected timestamp; "
          f"values outside the physical envelope: {summary['mapping']['gated'] or 'none'}")
    print_estimate(summary["consumer"])
    for reason in summary["not_diagnosed"]:
        print(f"  not diagnosed: {reason}")
    print(f"  faults raised: {summary['faults'] if summary['consumer'] is not None else 'n/a (no estimator attached)'}"
          + ("" if diagnosable else " (nothing could be diagnosed: see above)"))
    return status


def _print_log_replay(path: Path, vehicle, frame_consumer=None, as_json: bool = False) -> int:
    """Replay and print; returns the exit status: 2 unreadable, 1 nothing diagnosable, 0 success."""
    from gcs_pdm.logs.replay import exit_status, replay_log
    from gcs_pdm.logs.tables import FlightDataError
    from gcs_pdm.replay.vehicle import print_estimate

    try:
        summary = replay_log(path, vehicle, frame_consumer)
    except FlightDataError as exc:
        print(f"gcs-pdm replay: error: {exc}", file=sys.stderr)
        return 2
    status = exit_status(summary)
    if as_json:
        print(json.dumps(summary, default=str))
        return status
    print(f"{summary['path']}: {summary['autopilot']} log, {summary['frames']} frames in {summary['elapsed_s']:.3f} s; "
          f"frame time span {summary['frame_time_span_s']}")
    print("  frames by kind: " + ", ".join(f"{k}={v}" for k, v in summary["frames_by_kind"].items()))
    print(f"  packs: {summary['packs']}; motors by ESC instance: {summary['motors']}")
    for what, why in summary["left_out"].items():
        print(f"  left out: {what}: {why}")
    for what, why in summary["missing"].items():
        print(f"  missing: {what}: {why}")
    print_estimate(summary["consumer"])
    for reason in summary["not_diagnosed"]:
        print(f"  not diagnosed: {reason}")
    print(f"  faults raised: {summary['faults'] if summary['consumer'] is not None else 'n/a (no estimator attached)'}"
          + ("" if status == 0 else " (nothing could be diagnosed: see above)"))
    return status
