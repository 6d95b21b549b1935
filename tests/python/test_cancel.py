"""Ctrl-C stops the native work, not only the Python wait (crates/pybind/src/gil.rs sets the
worker's cancel flag, `trim_geom::cancel`)."""

import _thread
import signal
import threading
import time

import pytest

import trimctl

# Seconds after the interrupt by which the process must be quiet.
QUIET_WITHIN_S = 1.5


def test_ctrl_c_stops_the_native_work():
    """A registration interrupted while it runs raises KeyboardInterrupt at once, and the
    worker stops at its next iteration: the process's CPU time stops growing within about a
    second (without the cancel flag it grows by a core or more for the rest of the
    registration, half a minute with 1,000 field iterations)."""
    case = trimctl.synth(seed=2, scan_points=200_000, cad_points=100_000)
    # Long enough that the interrupt always lands while it runs: 200 iterations took 6 s in a
    # release build in 2026-11 and get faster as the field does.
    settings = {"cad_sample_points": 100_000, "field": {"iterations": 1000}}
    # Ctrl-C as Python's default handler takes it, whatever an earlier test in this process
    # (dask's cluster) left installed.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _interrupt_and_watch(case, settings)
    finally:
        signal.signal(signal.SIGINT, previous)


def _interrupt_and_watch(case, settings):
    # Interrupt once the registration has been busy for a while (it must still be running
    # when the interrupt lands: the CPU it burns before is checked below).
    timer = threading.Timer(2.0, _thread.interrupt_main)
    cpu_start = time.process_time()
    timer.start()
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        trimctl.register_path(
            case.cad_points, case.scan, case.path, cad_normals=case.cad_normals,
            init=case.scan_from_cad_nominal, settings=settings,
        )
    returned_s = time.monotonic() - t0
    busy_before = (time.process_time() - cpu_start) / returned_s
    timer.join()
    print(f"interrupted after {returned_s:.2f} s, {busy_before:.2f} cores busy before")
    assert returned_s < 2.0 + 0.5, f"KeyboardInterrupt took {returned_s:.2f} s"
    assert busy_before > 0.3, "the registration was not running when interrupted"

    # Quiet within about a second: the first half-second window with under 0.2 cores busy must
    # start within QUIET_WITHIN_S of the interrupt (one iteration, or one unchecked stage such
    # as the CAD curvature, which a debug build runs slowly), and stay quiet after.
    waited = 0.0
    while True:
        cpu0, wall0 = time.process_time(), time.monotonic()
        time.sleep(0.5)
        busy = (time.process_time() - cpu0) / (time.monotonic() - wall0)
        if busy < 0.2 or waited >= QUIET_WITHIN_S:
            break
        waited += 0.5
    print(f"quiet {waited:.1f} s after the interrupt ({busy:.3f} cores busy)")
    assert busy < 0.2 and waited <= QUIET_WITHIN_S, (
        f"the native worker still runs {waited:.1f} s after the interrupt: {busy:.2f} cores busy"
    )
    cpu0, wall0 = time.process_time(), time.monotonic()
    time.sleep(1.0)
    busy_after = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    assert busy_after < 0.2, f"busy again: {busy_after:.2f} cores"
