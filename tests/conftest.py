import os
import signal
import subprocess
import time
import urllib.request

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def grinder():
    from errormap.machine import load_machine
    return load_machine()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def wait_until_serving(proc, url: str, limit_s: float, log_path, what: str) -> None:
    """Poll ``url`` until it answers 200, failing the test if ``proc`` exits first or ``limit_s``
    passes (a local server started by a test; bounded, never unbounded waiting)."""
    deadline = time.monotonic() + limit_s
    while True:
        if proc.poll() is not None:
            pytest.fail(f"{what} exited with {proc.returncode}: {log_path.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            pass
        if time.monotonic() > deadline:
            pytest.fail(f"{what} did not answer within {limit_s} s")
        time.sleep(0.5)


def stop_process_group(proc) -> None:
    """End a server a test started in its own session: SIGTERM to its process group, then
    SIGKILL if it has not exited within 20 s."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=10)
