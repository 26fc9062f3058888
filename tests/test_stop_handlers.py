"""The stop handlers of every long-running process (soilocp.services.runtime.process.install_stop_handlers):
a SIGTERM stops the process cleanly, and a shutdown that hangs is bounded even when the hang holds
the GIL, where the Python watchdog thread cannot run.  Real OS processes and real signals."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from soilocp.services.supervisor.processes import STOP_TIMEOUT_S

# ``hang`` selects what the child does after its stop event is set: return at once, block in
# Python (the GIL free: the Python watchdog answers), or block in a native call that holds the
# GIL (ctypes.PyDLL keeps it across the call, as a native extension that forgets to release it).
CHILD = textwrap.dedent("""
    import ctypes, sys, threading
    from soilocp.services.runtime.process import install_stop_handlers
    from soilocp.services.runtime.log import JsonLog
    hang = sys.argv[1]
    stop = threading.Event()
    install_stop_handlers(stop, JsonLog("stop-test", "info"))
    print("ready", flush=True)
    stop.wait()
    if hang == "python":
        threading.Event().wait(60)
    elif hang == "native":
        ctypes.PyDLL(None).sleep(60)
    sys.exit(0)
""")


def _run(hang: str) -> tuple[int, str]:
    proc = subprocess.Popen([sys.executable, "-c", CHILD, hang], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        proc.send_signal(signal.SIGTERM)
        proc.wait(STOP_TIMEOUT_S)  # within what a supervisor allows before SIGKILL (raises otherwise)
        return proc.returncode, proc.stderr.read() + proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("hang, code, evidence", [
    ("none", 0, '"signal"'),
    ("python", 0, '"forced_exit"'),
    ("native", 1, "Timeout"),  # faulthandler's header, then every thread's stack
])
def test_a_hung_shutdown_ends_before_the_supervisors_kill_and_says_where(hang, code, evidence):
    returncode, output = _run(hang)
    assert returncode == code, output
    assert evidence in output, output
    if hang == "native":
        # the dump names the line that hung, and the Python watchdog never ran: faulthandler's ended it
        line = next(i for i, text in enumerate(CHILD.splitlines(), 1) if "PyDLL" in text)
        assert f"line {line} in <module>" in output, output
        assert '"forced_exit"' not in output, output


# The handler runs on the main thread between two bytecodes, possibly inside stop.wait() with the event's lock
# held (a service's main loop is `while not stop.wait(0.05)`): it must not take that lock itself.  The child
# calls the installed handler while holding the lock, as the signal would land, and then releases it.
HELD_LOCK = textwrap.dedent("""
    import signal, sys, threading, time
    from soilocp.services.runtime.process import install_stop_handlers
    stop = threading.Event()
    install_stop_handlers(stop, None)
    handler = signal.getsignal(signal.SIGTERM)
    t0 = time.monotonic()
    with stop._cond:
        handler(signal.SIGTERM, None)
    returned = time.monotonic() - t0
    print("handler returned in %.3f s; stop set: %s" % (returned, stop.wait(2.0)), flush=True)
    sys.exit(0)
""")


def test_the_handler_takes_no_lock_the_interrupted_main_thread_may_hold():
    proc = subprocess.run([sys.executable, "-c", HELD_LOCK], capture_output=True, text=True, timeout=20)
    assert proc.returncode == 0, proc.stderr[-2000:]
    line = proc.stdout.strip()
    assert line.startswith("handler returned in") and line.endswith("stop set: True"), (line, proc.stderr[-2000:])
    assert float(line.split()[3]) < 0.5, line
