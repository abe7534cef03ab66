"""`mlnseq review` driven as a user drives it: the command started as a process (its address read from what it
prints, stopped by a signal), and its page opened in Debian's chromium through Playwright (never a downloaded
browser: set-up installs chromium as root; without it, or without Playwright, the tests skip saying so). Shared by
tests/cli/test_review_cli.py and benchmarks/bench_review.py."""

from __future__ import annotations

import contextlib
import http.client
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
ARGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync")
ADDRESS = re.compile(r" at (http://\S+/) ")


def missing() -> str | None:
    """Why no browser test can run here, or None."""
    chromium = CHROMIUM if os.path.exists(CHROMIUM) else shutil.which("chromium")
    if chromium is None:
        return "Debian's chromium is not installed (set-up installs it as root: apt-get install chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the Python package playwright is not installed (pip install '.[test]')"
    return None


@contextlib.contextmanager
def served(*args: str | Path, cwd: Path | None = None, stop: int = signal.SIGTERM,
           port: int = 0) -> Iterator[tuple[str, list]]:
    """`mlnseq review ARGS --port PORT` running: (its address, its printed lines so far); stopped by ``stop`` at the
    end, which must end it cleanly (exit 0, 'stopped' printed)."""
    command = [sys.executable, "-m", "mlnseq_cli.main", "review", *map(str, args), "--port", str(port)]
    process = subprocess.Popen(command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    printed, reader = [], None
    try:
        line = process.stdout.readline()
        printed.append(line)
        match = ADDRESS.search(line)
        if match is None:
            process.kill()
            raise AssertionError(f"review printed no address: {line!r}\n{process.stderr.read()}")
        reader = threading.Thread(target=lambda: printed.extend(text.rstrip("\n") for text in process.stdout),
                                  daemon=True)  # every later line, as it comes (the pipe's buffer read too)
        reader.start()
        yield match.group(1), printed
    finally:
        if process.poll() is None:
            process.send_signal(stop)
        process.wait(timeout=20)
        if reader is not None:
            reader.join(timeout=5)
        err = process.stderr.read()
    assert process.returncode == 0, f"review ended with {process.returncode}: {err}"
    assert printed[-1].startswith(f"review: stopped ({signal.Signals(stop).name})"), printed


@contextlib.contextmanager
def browser(width: int = 1400, height: int = 900) -> Iterator:
    """A page of a fresh headless chromium, collecting its console errors and uncaught exceptions in
    ``page.errors``."""
    from playwright.sync_api import sync_playwright

    chromium = CHROMIUM if os.path.exists(CHROMIUM) else shutil.which("chromium")
    with sync_playwright() as playwright, tempfile.TemporaryDirectory(prefix="review-profile-") as profile:
        context = playwright.chromium.launch_persistent_context(
            profile, executable_path=chromium, args=list(ARGS), headless=True,
            viewport={"width": width, "height": height})
        try:
            page = context.new_page()
            page.errors = []
            page.on("console", lambda m: m.type == "error" and page.errors.append(f"console: {m.text}"))
            page.on("pageerror", lambda error: page.errors.append(f"exception: {error}"))
            yield page
        finally:
            context.close()


def until(page, expression: str, timeout: float = 10.0):
    """Wait for a JavaScript expression to be truthy (polled: the page's CSP forbids Playwright's eval), and return
    its value."""
    deadline = time.monotonic() + timeout
    while True:
        value = page.evaluate(expression)
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout:g} s: {expression} (page errors: {page.errors})")
        time.sleep(0.02)


def opened(page, url: str, timeout: float = 10.0) -> float:
    """Open the review page; the seconds until its first recording was drawn."""
    started = time.monotonic()
    page.goto(url)
    until(page, "window.review && window.review.drawnMs !== null", timeout)
    return time.monotonic() - started


def request(url: str, method: str, path: str, headers: dict[str, str], body: bytes = b"") -> tuple[int, str]:
    """One raw request (the path sent as written, never normalised); (status, body)."""
    host, port = url.split("//")[1].strip("/").split(":")
    connection = http.client.HTTPConnection(host, int(port), timeout=10)
    connection.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
    for name, value in {"Host": f"{host}:{port}", **headers}.items():
        connection.putheader(name, value)
    connection.endheaders(body or None)
    reply = connection.getresponse()
    return reply.status, reply.read().decode()


def test_requests_from_elsewhere_outside_the_page_or_too_large_are_refused(trials, tmp_path):
    saved = tmp_path / "labels.csv"
    save = json.dumps({"index": 0, "segments": [[0, 106, "approach"]]}).encode()
    as_json = {"Content-Type": "application/json", "Content-Length": str(len(save))}
    with served(trials["model"], "--source", trials["csv"], "--save", saved) as (url, _):
        own = url.rstrip("/")
        assert request(url, "GET", "/", {})[0] == 200
        assert request(url, "GET", "/api/recordings", {"Origin": own})[0] == 200
        assert request(url, "GET", "/api/recordings", {"Origin": "http://evil.example"})[0] == 403
        assert request(url, "GET", "/", {"Host": "evil.example:80"})[0] == 403  # a rebound DNS name
        assert request(url, "POST", "/api/save", {**as_json, "Origin": "http://evil.example"}, save)[0] == 403
        for outside in ("/../pyproject.toml", "/%2e%2e/%2e%2e/pyproject.toml", "/review.js/../../review.py",
                        "/stages/review.py", "/mln.mlnseq", "//etc/passwd", "/api/../../etc/passwd"):
            status, body = request(url, "GET", outside, {})
            assert status == 404 and "[tool" not in body and "root:" not in body, outside
        status, body = request(url, "POST", "/api/save", {"Content-Type": "application/json",
                                                          "Content-Length": str(8 << 20)})
        assert status == 413 and "at most" in body  # refused before a byte of it is read
        assert request(url, "POST", "/api/save", {**as_json, "Content-Type": "text/plain"}, save)[0] == 415
        bad = json.dumps({"index": 0, "segments": [[0, 50, "approach"]]}).encode()
        status, body = request(url, "POST", "/api/save", {**as_json, "Content-Length": str(len(bad))}, bad)
        assert status == 400 and "cover" in body
        assert request(url, "GET", "/api/explain?index=7&frame=1", {})[0] == 400
        assert not saved.exists()
        assert request(url, "POST", "/api/save", as_json, save)[0] == 200
    assert pl.read_csv(saved).rows() == [(TRIALS[0], 0, 106, "approach", "frames")]
