"""Speed of the state estimator, the diagnosis pipeline and the Monte Carlo prediction (issues 6
and 18), beside progpy's BatteryCircuit particle filter and Monte Carlo predictor.

Prints one line per figure and, last, ONE JSON object. Every figure is ``{"wall", "cpu", "floor",
"loadavg_1min"}``: best-of wall time and process CPU time (``time.process_time``), with the load
average when measured — on a shared machine CPU time is the figure to trust.

- ``update_4packs_2motors_us``: one estimator update of all four packs and both motors (the two
  compiled filter steps, ``PackFilterBank.step`` and ``MotorThermalFilter.step``) — floor 80 µs;
- ``consume_per_frame_us``: ``StateEstimator.consume`` per telemetry frame of a synthetic flight;
- ``pipeline_per_frame_us``: the whole ``DiagnosisPipeline`` per frame (estimator, detectors, pack
  health fits every 60 s and the prognosis' Monte Carlo every 30 s of message time, amortised)
  — floor 60 µs;
- ``pipeline_per_frame_no_mission_us``: the same without a mission, so without the Monte Carlo
  (what a replay of a tlog costs per frame) — floor 60 µs too. Both are the best run over 10 s of
  runs (``windowed_figure``: longer than the host's phases), with ``median_cpu`` and the yardstick;
- ``pipeline_breakdown``: one run with a mission split into the pack-health fits, the prognosis,
  the estimator and the rest (detectors and bookkeeping), µs per frame, and how many prognosis
  checks ran the Monte Carlo or re-used the latest prediction (``diagnosis/prognosis.py``);
- ``mc_100_30min_ms``: a 100-sample Monte Carlo prediction 30 minutes ahead at 1 s steps (without
  the median trajectories; ``mc_100_30min_with_trajectories_ms`` with them) — floor 15 ms; from
  the estimator as the update figure leaves it (samples fail 1–360 s ahead), and
  ``mc_100_30min_from_flight_end_ms`` from the flight's end state (samples fly 390–710 s);
  ``mc_100_30min_extended_ms`` the same prediction with every pack on the extended variant (the
  default of a new fit, issue 15), from an estimator that followed 10 minutes of that model's own
  flight (samples fly 890–1080 s) — floor 15 ms too;
- progpy (if installed): ``progpy_pf_update_100_us`` — ParticleFilter over BatteryCircuit (one
  cell, 100 particles), one update; ``progpy_mc_100_30min_ms_est`` — its MonteCarlo predictor,
  measured on 10 samples and scaled ×10 (the full run takes tens of seconds).

Run: ``PYTHONPATH=$PWD python benchmarks/bench_estimate.py`` (``--extended-only``: just
``mc_100_30min_extended_ms``, with ``host_yardstick_ms`` before and after it: ~1.2 ms in the
host's fast phase, ~2.0 in its slow one, which slows every compiled loop alike)
"""
from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import host_yardstick_ms, loadavg, timed  # noqa: E402

from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
from gcs_pdm.estimation.synthetic import fly_synthetic
from gcs_pdm.models.params import default_set
from gcs_pdm.sim.truth import true_parameters


def figure(t: dict, scale: float, floor: float | None, unit: str) -> dict:
    out = {"wall": round(t["wall_s"] * scale, 1), "cpu": round(t["cpu_s"] * scale, 1), "floor": floor,
           "unit": unit, "loadavg_1min": t["loadavg_1min"]}
    if floor is not None:
        out["reached_cpu"] = out["cpu"] <= floor
    return out


def main() -> dict:
    ps = default_set()
    flight = fly_synthetic(true_parameters(), np.random.default_rng(7), duration_s=1200.0)
    est = StateEstimator(ps)
    for fr in flight.frames:
        est.consume(fr)
    # warm-up done by the flight; now the batched update of everything
    idx4, idx2 = np.arange(4), np.arange(2)
    v, _ = est.packs.voltage()
    tp, _ = est.packs.temperature()
    tm, _ = est.motors.temperature()

    def update():
        est.packs.step(idx4, np.full(4, 0.5), np.full(4, 12.0), 20.0, v, tp)
        est.motors.step(idx2, np.full(2, 0.5), np.full(2, 12.0), 20.0, tm)

    figures = {"update_4packs_2motors_us": figure(timed(update, 5, 200), 1e6, 80, "µs")}

    def consume_all():
        e = StateEstimator(ps)
        for fr in flight.frames:
            e.consume(fr)

    n = len(flight.frames)
    figures["consume_per_frame_us"] = figure(timed(consume_all, 3, 1), 1e6 / n, None, "µs")

    def pipeline_all():
        p = DiagnosisPipeline(ps)
        p.set_mission(FutureLoad(np.diff(flight.time_s, prepend=flight.time_s[0]), flight.shaft_power_w, 20.0),
                      flight.time_s[0])
        for fr in flight.frames:
            p.consume(fr)

    # the best run over a window longer than the host's phases of 1-5 s (``windowed_figure``; a run
    # is about a second), as ``mc_100_30min_extended_ms``
    pipeline_all()
    figures["pipeline_per_frame_us"] = windowed_figure(pipeline_all, PIPELINE_WINDOW_S, 1e6 / n, 60, "µs")

    def pipeline_no_mission():
        p = DiagnosisPipeline(ps)
        for fr in flight.frames:
            p.consume(fr)

    # without a mission the prognosis' Monte Carlo does not run: what is left is the per-frame work
    figures["pipeline_per_frame_no_mission_us"] = windowed_figure(pipeline_no_mission, PIPELINE_WINDOW_S, 1e6 / n, 60,
                                                                  "µs")
    figures["pipeline_breakdown"] = pipeline_breakdown(ps, flight)

    load = FutureLoad.constant(1000.0, 1800.0, 1.0)
    rng = np.random.default_rng(0)
    figures["mc_100_30min_ms"] = figure(timed(lambda: predict_from_estimator(
        est, load, rng=rng, n_samples=100, trajectories=False), 5, 3), 1e3, 15, "ms")
    figures["mc_100_30min_with_trajectories_ms"] = figure(timed(lambda: predict_from_estimator(
        est, load, rng=rng, n_samples=100, trajectories=True), 3, 2), 1e3, None, "ms")
    # the two above predict from ``est`` as the update figure left it (1,000 more steps at 12 A):
    # its samples fail 1–360 s ahead. From the flight's own end state they fly 390–710 s, the
    # heavier case (the kernel's work follows the samples flown, not the horizon)
    at_flight_end = StateEstimator(ps)
    for fr in flight.frames:
        at_flight_end.consume(fr)
    figures["mc_100_30min_from_flight_end_ms"] = figure(timed(lambda: predict_from_estimator(
        at_flight_end, load, rng=np.random.default_rng(0), n_samples=100, trajectories=False), 5, 3), 1e3, 15, "ms")
    figures["mc_100_30min_extended_ms"] = extended_figure()
    figures.update(progpy_reference())
    for name, f in figures.items():
        if isinstance(f, dict) and "cpu" in f:
            print(f"{name:<36} wall {f['wall']:>9} cpu {f['cpu']:>9} {f['unit']:<3} floor {f['floor']}  "
                  f"(load {f['loadavg_1min']})")
    return {"benchmark": "bench_estimate", "frames_per_flight": n, "flight_duration_s": round(flight.duration_s, 1),
            "figures": figures}


EXTENDED_WINDOW_S = 8.0
#: the same for the pipeline's per-frame figures (a run of the 1200-s flight is about a second)
PIPELINE_WINDOW_S = 10.0


def extended_figure(window_s: float = EXTENDED_WINDOW_S) -> dict:
    """The best single call over ``window_s`` seconds of calls, with their median and the host's
    yardstick just before and after (``measure.host_yardstick_ms``).

    The host under this VM runs in phases of 1-5 s; in its slow one every compiled loop, a fixed
    reference loop included, takes ~1.4-1.7x the CPU (docs/notes/2026-11-27-extended-mc-5.md). A
    best of a few calls lands in whichever phase the process starts in; a window longer than a phase
    measures the code, as timeit's best-of does, and the median says what a busy host gives."""
    call = extended_monte_carlo()
    call()
    return windowed_figure(call, window_s, 1e3, 15, "ms")


def windowed_figure(call, window_s: float, scale: float, floor: float | None, unit: str) -> dict:
    """``figure`` of the best of ``call``'s runs over ``window_s`` seconds (at least three), with their
    median CPU (``median_cpu``, same scale) and the host's yardstick before and after."""
    import time

    before = host_yardstick_ms()
    cpu, wall = [], []
    end = time.perf_counter() + window_s
    while time.perf_counter() < end or len(cpu) < 3:
        w0, c0 = time.perf_counter(), time.process_time()
        call()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    out = figure({"wall_s": min(wall), "cpu_s": min(cpu), "loadavg_1min": loadavg()}, scale, floor, unit)
    out["median_cpu"] = round(float(np.median(cpu)) * scale, 1)
    out["calls"] = len(cpu)
    out["host_yardstick_ms"] = {"before": before, "after": host_yardstick_ms()}
    return out


def extended_monte_carlo():
    """A 100-sample, 30-minute prediction of four packs on the extended variant (LiPo defaults),
    from an estimator that followed 10 minutes of that model flown at 8-28 A: the call to time."""
    import dataclasses

    from gcs_pdm.frames import PackFrame
    from gcs_pdm.models import kernel
    from gcs_pdm.models.params import PACK_NAMES, extended_default

    ps = default_set()
    for n in PACK_NAMES:
        ps = ps.with_pack(n, dataclasses.replace(ps.packs[n], model="extended", extended=extended_default("lipo")))
    rng = np.random.default_rng(3)
    current = np.repeat(rng.uniform(8.0, 16.0, 5), 120)
    current[:60] = 28.0
    ext = np.stack([ps.packs[n].extended_vector() for n in PACK_NAMES])
    run = kernel.simulate_packs(ext, kernel.initial_extended_state(ext, 0.95, 20.0, 0.0), np.ones(current.size),
                                current, 20.0, variant="extended")
    est = StateEstimator(ps)
    for k in range(current.size):
        for b, n in enumerate(PACK_NAMES):
            est.consume(PackFrame(float(k), n, voltage_v=float(run.voltage[b, k] + rng.normal(0, 0.03)),
                                  current_a=float(current[k]), temperature_c=float(run.temperature[b, k])))
    load = FutureLoad.constant(1000.0, 1800.0, 1.0)
    return lambda: predict_from_estimator(est, load, rng=np.random.default_rng(0), n_samples=100,
                                          trajectories=False)


def pipeline_breakdown(ps, flight) -> dict:
    """Where ``pipeline_per_frame_us`` goes, per frame (CPU µs, one run with a mission): the pack
    health fits (every 60 s of message time), the prognosis (its Monte Carlo runs and re-uses), the
    estimator (its pack and motor steps, ``StateEstimator._pack`` and ``_motor``) and the rest (the motor
    detector, the model-mismatch advisory, the pack-health record, the dispatch); with how often the
    prognosis ran its Monte Carlo. The timers themselves add ≈ 1 µs per frame."""
    import time

    p = DiagnosisPipeline(ps)
    p.set_mission(FutureLoad(np.diff(flight.time_s, prepend=flight.time_s[0]), flight.shaft_power_w, 20.0),
                  flight.time_s[0])
    spent = {"pack_health_fits": 0.0, "prognosis": 0.0, "estimator": 0.0}

    def timing(name, fn):
        def wrapped(*args):
            c0 = time.process_time()
            try:
                return fn(*args)
            finally:
                spent[name] += time.process_time() - c0
        return wrapped

    p.pack_health.check = timing("pack_health_fits", p.pack_health.check)
    p.prognosis.check = timing("prognosis", p.prognosis.check)
    # the pipeline calls the estimator's pack and motor steps directly (ambient frames go to its handler,
    # looked up on the first one)
    est = p.estimator
    est._pack, est._motor = timing("estimator", est._pack), timing("estimator", est._motor)
    c0 = time.process_time()
    for fr in flight.frames:
        p.consume(fr)
    total = time.process_time() - c0
    n = len(flight.frames)
    out = {k: round(v * 1e6 / n, 1) for k, v in spent.items()}
    out["detectors_and_bookkeeping"] = round((total - sum(spent.values())) * 1e6 / n, 1)
    status = p.prognosis.status(p.estimator.time_s)
    out.update(unit="µs per frame", prognosis_monte_carlo_runs=status["runs"],
               prognosis_checks_reusing=status["reused"])
    return out


def progpy_reference() -> dict:
    try:
        from progpy.models import BatteryCircuit
        from progpy.predictors import MonteCarlo
        from progpy.state_estimators import ParticleFilter
        from progpy.uncertain_data import MultivariateNormalDist
    except ImportError:
        return {"progpy": "not installed"}
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = BatteryCircuit()
        x0 = m.initialize()
        pf = ParticleFilter(m, x0, num_particles=100)
        u = m.InputContainer({"i": 2.0})
        x = x0
        t = 0.0
        zs = []
        for _ in range(30):
            t += 1.0
            x = m.next_state(x, u, 1.0)
            zs.append((t, m.output(x)))
        k = [0]

        def pf_step():
            tt, z = zs[k[0] % len(zs)]
            pf.estimate(tt + 30.0 * (k[0] // len(zs)), u, z)
            k[0] += 1

        out["progpy_pf_update_100_us"] = figure(timed(pf_step, 3, 20), 1e6, None, "µs")
        mc = MonteCarlo(m)
        x_dist = MultivariateNormalDist(list(x.keys()), list(x.values()), np.diag([1e-6] * len(x)))

        def future_load(t, x=None):
            return u

        t = timed(lambda: mc.predict(x_dist, future_load, n_samples=10, dt=1.0, horizon=1800, save_freq=60), 1, 1)
        out["progpy_mc_100_30min_ms_est"] = figure(t, 10 * 1e3, None, "ms")
    return out


if __name__ == "__main__":
    if sys.argv[1:] == ["--extended-only"]:  # the one figure issue 32 asks of the extended circuit, alone
        print(json.dumps({"benchmark": "bench_estimate", "figures": {"mc_100_30min_extended_ms": extended_figure()}}))
    else:
        print(json.dumps(main()))
