"""Run ``phireman`` as a user does: the console script installed in this venv, in a subprocess, in a
directory of the test's own. Nothing here imports ``mission``: these tests see only the command
line (exit status, messages, files, the HTTP port a ``--serve`` opens), so they keep working
however the package is laid out inside."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

__all__ = ["PHIREMAN", "VENV_BIN", "user_env", "run", "Served", "http_get"]

VENV_BIN = Path(sys.executable).parent
"""The venv's bin directory: where ``pip install`` put the ``phireman`` console script."""
PHIREMAN = str(VENV_BIN / "phireman")


def user_env(home: Path | None = None) -> dict[str, str]:
    """The environment of a user who ran ``. .venv/bin/activate``: the venv first on PATH (and
    ``HOME`` moved to ``home`` when given, so that ``~/...`` in a documented command stays inside
    the test's directory)."""
    env = dict(os.environ)
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(VENV_BIN.parent)
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("PYTHONPATH", None)
    if home is not None:
        env["HOME"] = str(home)
    return env


def run(
    cmd: list[str] | str, cwd: Path, timeout: float = 300, home: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """Run ``cmd`` (an argv list, or a shell line run by bash as typed) in ``cwd``; output kept."""
    shell = isinstance(cmd, str)
    return subprocess.run(
        ["bash", "-c", cmd] if shell else cmd,
        cwd=cwd,
        env=user_env(home),
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def http_get(url: str, timeout: float = 10.0) -> tuple[int, bytes]:
    """(status, body) of a GET; an HTTP error status is returned, not raised."""
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


class Served:
    """A command that serves until stopped (``--serve``): started in its own process group,
    its output read by threads, stopped with SIGINT (as Ctrl-C) then SIGKILL at the end.

    ``cmd`` as in :func:`run`."""

    def __init__(self, cmd: list[str] | str, cwd: Path, home: Path | None = None) -> None:
        shell = isinstance(cmd, str)
        self.proc = subprocess.Popen(
            ["bash", "-c", cmd] if shell else cmd,
            cwd=cwd,
            env=user_env(home),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            text=True,
            start_new_session=True,  # its own process group: bash and phireman stop together
        )
        self.out: list[str] = []
        self.err: list[str] = []
        self._threads = [
            threading.Thread(target=self._pump, args=(s, buf), daemon=True)
            for s, buf in ((self.proc.stdout, self.out), (self.proc.stderr, self.err))
        ]
        for t in self._threads:
            t.start()

    @staticmethod
    def _pump(stream, buf: list[str]) -> None:
        for line in stream:
            buf.append(line)

    @property
    def output(self) -> str:
        return "".join(self.out) + "".join(self.err)

    def wait_for(self, pattern: str, deadline_s: float = 120.0) -> re.Match[str]:
        """The first match of ``pattern`` in the output; AssertionError if the process ends or the
        deadline passes first."""
        end = time.monotonic() + deadline_s
        rx = re.compile(pattern)
        while time.monotonic() < end:
            m = rx.search(self.output)
            if m:
                return m
            if self.proc.poll() is not None:
                time.sleep(0.2)  # the last lines
                m = rx.search(self.output)
                if m:
                    return m
                raise AssertionError(
                    f"exited with {self.proc.returncode} before printing /{pattern}/:\n"
                    + self.output[-3000:]
                )
            time.sleep(0.1)
        raise AssertionError(f"no /{pattern}/ within {deadline_s} s:\n" + self.output[-3000:])

    def get_json(self, url: str) -> dict:
        status, body = http_get(url)
        assert status == 200, f"GET {url}: HTTP {status}: {body[:300]!r}"
        return json.loads(body)

    def stop(self) -> int:
        """Ctrl-C, then kill after 20 s; the exit status."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGINT)
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)
            except ProcessLookupError:
                pass
        for t in self._threads:
            t.join(timeout=5)
        return self.proc.returncode

    def __enter__(self) -> Served:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
