"""``ltm view`` under hostile and busy clients: half-sent requests that hang up, a burst of
concurrent ``/relight`` requests, Ctrl-C with silent clients still connected."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from urllib.parse import urlsplit

import pytest
from pipeline_helpers import served_view


@pytest.fixture(scope="module")
def view(far_store):
    """``ltm view far_store`` as a real process: yields (process, (host, port))."""
    with served_view(far_store) as (proc, url):
        url = urlsplit(url)
        yield proc, (url.hostname, url.port)


def get(address: tuple[str, int], path: str, timeout: float = 60.0) -> tuple[int, bytes]:
    """One plain GET on a new connection: (status, body)."""
    with socket.create_connection(address, timeout=timeout) as sock:
        sock.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{address[1]}\r\n"
                     "Connection: close\r\n\r\n".encode())
        data = b""
        while chunk := sock.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), body


def stderr_so_far(proc: subprocess.Popen) -> str:
    """What the server has written to stderr until now (without waiting for more)."""
    fd = proc.stderr.fileno()
    os.set_blocking(fd, False)
    try:
        return os.read(fd, 1 << 20).decode(errors="replace")
    except BlockingIOError:
        return ""
    finally:
        os.set_blocking(fd, True)


def half_request_and_hang_up(address: tuple[str, int], how: int) -> None:
    """Send part of a request line or of the headers, then leave (a reset for some)."""
    sock = socket.create_connection(address, timeout=10)
    part = (b"GET /relight?u=0.1&v=0", b"GET / HTTP/1.1\r\nHost: 127.0", b"GE")[how % 3]
    sock.sendall(part)
    if how % 2:  # an abortive close: RST instead of FIN
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
    sock.close()


def test_half_requests_that_hang_up_leave_no_traceback_and_the_server_answers(view):
    proc, address = view
    with ThreadPoolExecutor(20) as pool:
        list(pool.map(lambda i: half_request_and_hang_up(address, i), range(100)))
    status, body = get(address, "/relight?u=0.2&v=-0.1")
    assert status == 200 and body.startswith(b"\x89PNG")
    assert get(address, "/relight?u=0&v=0&ev=nan")[0] == 400  # today's bad-input rules
    assert get(address, "/nowhere")[0] == 404
    assert proc.poll() is None
    assert stderr_so_far(proc) == ""  # no traceback, no line: the clients just left


def test_concurrent_relight_requests_are_all_answered(view):
    """Each on its own connection at once: none reset (the standard library's backlog of 5
    dropped some), all answered."""
    _, address = view
    paths = [f"/relight?u={(i % 10) / 10 - 0.5:.2f}&v={(i // 10) / 20 - 0.5:.2f}"
             for i in range(200)]
    with ThreadPoolExecutor(len(paths)) as pool:
        answers = list(pool.map(lambda p: get(address, p), paths))
    assert [status for status, _ in answers] == [200] * len(paths)
    assert all(body.startswith(b"\x89PNG") for _, body in answers)


def test_ctrl_c_stops_it_with_silent_clients_connected(view):
    """After the module's other tests: a client silent mid-request does not hold Ctrl-C."""
    proc, address = view
    silent = [socket.create_connection(address) for _ in range(5)]
    for sock in silent:
        sock.sendall(b"GET /info HTTP/1.1\r\n")  # and nothing more
    time.sleep(0.3)  # accepted, their threads waiting for the rest
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=10)  # generous: it takes well under a second
    finally:
        for sock in silent:
            sock.close()
    assert proc.returncode == 0
    assert err.strip().splitlines() == ["ltm view: stopped"]  # no traceback from any request
