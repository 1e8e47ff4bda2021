"""A replay does not make the frames its consumer ignores (``consumed_frame_types``): the summary,
the pipeline's report and the trace must be those of the same replay handing every frame over —
on the fixture flights, the real logs of the shared corpus and randomly generated damaged logs
(tests/test_frame_columns.py's generator: reboots, jumps, out-of-order and hostile times, foreign
systems, receive-time fallback, frames made message by message)."""
from __future__ import annotations

import glob
import logging
import random
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/ is not a package
from test_frame_columns import MAPPERS, random_log  # noqa: E402

import gcs_pdm.mavlink.frame_columns as frame_columns  # noqa: E402
from gcs_pdm.diagnosis.pipeline import CONSUMED_FRAME_TYPES, DiagnosisPipeline  # noqa: E402
from gcs_pdm.estimation.estimator import ignore_frame  # noqa: E402
from gcs_pdm.frames import (AirdataFrame, AmbientFrame, MissionProgressFrame, MotorFrame, PackFrame,  # noqa: E402
                            PositionFrame, WindFrame, StatusFrame, StatusTextFrame, FRAME_KINDS)
from gcs_pdm.mavlink.mapping import FrameMapper  # noqa: E402
from gcs_pdm.mavlink.replay import replay_tlog  # noqa: E402
from gcs_pdm.vehicle.presets import PRESETS  # noqa: E402
from gcs_pdm.replay.vehicle import TracedPipeline, pipeline_for, replay_vehicle  # noqa: E402
from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO / ".." / "shared"
REAL_LOGS = sorted(glob.glob(str(SHARED / "tlogs" / "*.tlog"))) + sorted(glob.glob(str(SHARED / "logs" / "*.tlog")))
FIXTURE_LOGS = sorted(glob.glob(str(REPO / "fixtures" / "flights" / "*.tlog")))
VOLATILE = ("elapsed_s", "messages_per_s")

EXAMPLES = {
    PackFrame: PackFrame(1.0, "battery1", 22.0, 10.0, 25.0),
    MotorFrame: MotorFrame(1.0, "fwd", 12.0, 5000.0, 40.0),
    AmbientFrame: AmbientFrame(1.0, 15.0),
    PositionFrame: PositionFrame(1.0, 47.0, 8.0, 500.0, 100.0, 1.0, 0.0, 0.0),
    AirdataFrame: AirdataFrame(1.0, 18.0, 17.0, 0.5, 55.0, 90.0),
    StatusFrame: StatusFrame(1.0, True, "AUTO", 4),
    MissionProgressFrame: MissionProgressFrame(1.0, 3, None),
    StatusTextFrame: StatusTextFrame(1.0, 6, "hello"),
    WindFrame: WindFrame(1.0, 6.0, 270.0),
}


class AllFrames:
    """The same consumer, declaring nothing: the replay makes and hands over every frame."""

    def __init__(self, consumer):
        self.consumer = consumer

    def __call__(self, frame) -> None:
        self.consumer(frame)

    def report(self) -> dict:
        return self.consumer.report()


@pytest.fixture
def handed_due(monkeypatch):
    """How many passed-over frames the replays made because they were due (a sample's instant)."""
    made = []
    real = frame_columns.Chunk.passed_frame
    monkeypatch.setattr(frame_columns.Chunk, "passed_frame", lambda self, j: made.append(j) or real(self, j))
    return made


def both_ways(path, make_mapper, make_consumer) -> tuple[dict, dict]:
    """The summary (consumer report included) of a replay passing frames over and of one handing
    all; an error the consumer raises (a damaged log can break the estimator) as its repr."""
    out = []
    for wrap in (lambda c: c, AllFrames):
        consumer = make_consumer()
        try:
            summary = replay_tlog(path, mapper=make_mapper(), frame_consumer=wrap(consumer)).to_dict()
            for k in VOLATILE:
                summary.pop(k)
        except Exception as exc:  # noqa: BLE001 - compared: both ways must fail alike
            summary = {"error": repr(exc)}
        finally:
            getattr(consumer, "close", lambda: None)()
        out.append(summary)
    return out[0], out[1]


def test_the_declared_types_are_the_handled_ones():
    """Every frame type outside ``consumed_frame_types`` ends in ``ignore_frame`` (so passing it over
    changes nothing but the count), and every type in it does not — for the paper's aircraft and
    every preset's description."""
    assert set(EXAMPLES) == set(FRAME_KINDS.values())
    for desc in PRESETS.values():  # the paper's aircraft is edge540
        pipeline = pipeline_for(desc)
        for cls, frame in EXAMPLES.items():
            assert (pipeline._handler_for(frame) is ignore_frame) == (cls not in CONSUMED_FRAME_TYPES), (desc, cls)
        pipeline.passed_over(5)
        pipeline.consume(EXAMPLES[PositionFrame])
        assert pipeline.frames == 6


#: real logs whose 0.7 s samples never fall on a passed-over frame: the traced pipeline takes the
#: flight conditions' frames (status, position, air data: estimation.flight_conditions) as well, and
#: in these logs the frames it passes over (wind, mission progress, status text) never come first at
#: a sample's instant (test_randomly_damaged_logs keeps the path covered: > 100 due frames handed)
NO_DUE_PASSED_OVER = {"ahmadkhanfar_TLOG_test.tlog", "arduplane_sitl_stock.tlog"}


def _traced(desc, about, period_s=30.0):
    return lambda: TracedPipeline(desc, about, period_s=period_s, background=False)


@pytest.mark.parametrize("path", FIXTURE_LOGS + REAL_LOGS, ids=lambda p: Path(p).name)
def test_fixture_and_real_logs_as_the_replay_command_runs_them(path, handed_due):
    """(A fixture flight's pack frames come at 20 Hz: its samples fall on them; the real logs'
    samples fall on passed-over frames too.)"""
    logging.disable(logging.WARNING)
    try:
        desc, about = replay_vehicle(Path(path), None)
        desc = desc or PRESETS["edge540"]  # as ``gcs-pdm replay``: none derived is the paper's aircraft
        mapper = lambda: FrameMapper(frame_mapping(desc), envelope=envelope(desc))  # noqa: E731
        skipped, whole = both_ways(path, mapper, _traced(desc, about))
        assert skipped == whole and "error" not in skipped
        assert skipped["consumer"]["frames"] == skipped["frames"]
        # a short period: most samples fall on a passed-over frame
        skipped, whole = both_ways(path, mapper, _traced(desc, about, period_s=0.7))
        assert skipped == whole and "error" not in skipped
        trace = skipped["consumer"]["trace"]
        skipped, whole = both_ways(path, FrameMapper, DiagnosisPipeline)  # no samples: nothing handed but its types
        assert skipped == whole
    finally:
        logging.disable(logging.NOTSET)
    assert handed_due or path in FIXTURE_LOGS or not trace or Path(path).name in NO_DUE_PASSED_OVER


def test_randomly_damaged_logs(tmp_path, handed_due):
    logging.disable(logging.WARNING)
    rng = random.Random(21)
    passed, traced, failed = [], 0, 0
    real_chunks = frame_columns._chunks
    try:
        frame_columns._chunks = lambda *a: (passed.append(c.passed) or c for c in real_chunks(*a))
        for k in range(24):
            path = tmp_path / f"damaged_{k}.tlog"
            path.write_bytes(random_log(rng, rng.randrange(50, 1500)))
            for name, make_mapper in MAPPERS.items():
                for period_s in (30.0, 0.3):
                    skipped, whole = both_ways(path, make_mapper, _traced(PRESETS["edge540"], {"source": "none"}, period_s))
                    assert skipped == whole, (k, name, period_s)
                    failed += "error" in skipped
                    traced += len(skipped.get("consumer", {}).get("trace", []))
    finally:
        frame_columns._chunks = real_chunks
        logging.disable(logging.NOTSET)
    # frames were passed over, due ones handed over, samples taken; most replays ran to their end
    assert sum(passed) > 1000 and len(handed_due) > 100 and traced > 100 and failed < 0.2 * 24 * len(MAPPERS) * 2
