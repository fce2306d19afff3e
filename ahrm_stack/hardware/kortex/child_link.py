"""The parent side of the link: ``kortex_api`` in a process of its own.

:class:`ChildLink` starts :mod:`ahrm_stack.hardware.kortex.vendor_link` under a given interpreter (a virtual
environment with ``kortex_api`` and its ``protobuf`` 3.20 pin; default this one) and talks to it
over its stdin / stdout, one JSON line per request and per answer: plain values only. This process
never imports ``kortex_api`` or ``protobuf``. It has the same :meth:`call` as
:class:`~ahrm_stack.hardware.kortex.vendor_link.VendorLink`.

A child that exits, or does not answer a call within the call's own timeout plus
``margin_ms``, is killed and the call fails with ``LinkError('dead', ...)``: no Stop can be sent
through it any more; the arm's own ``connection_inactivity_timeout`` (deploy.yaml) is then the only
guard, and the child's socket closing with it ends the session on the arm. The child runs in a
session of its own and ignores SIGINT: a Ctrl-C stops the adapter's loop, which then stops the arm
through a child that is still there. A call interrupted while it waits for its answer (Ctrl-C,
SIGTERM: a ``KeyboardInterrupt`` in this process) leaves that answer in the pipe: the next call
sends its request first, then reads and drops the owed answer, then reads its own, so a Stop after
a Ctrl-C is neither delayed nor answered with another call's result.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Sequence

from ahrm_stack.hardware.kortex.vendor_link import LinkError

VENDOR_LINK = Path(__file__).resolve().with_name("vendor_link.py")
#: Runs vendor_link.py as the main module without putting its folder on the child's sys.path.
_BOOT = "import runpy, sys; runpy.run_path(sys.argv[1], run_name='__main__')"


class ChildLink:
    """``kortex_api`` in a child process.

    Args:
        python: the child's interpreter ('' or None: ``sys.executable``).
        start_timeout_ms: the child must import ``kortex_api`` and say ready within this (ms).
        margin_ms: each call must be answered within its ``timeout_ms`` plus this (ms).
        path: folders put in front of the child's ``PYTHONPATH`` (tests: the fake ``kortex_api``).
    """

    def __init__(self, python: str | None = None, *, start_timeout_ms: int = 20000,
                 margin_ms: int = 250, path: Sequence[str | Path] = ()) -> None:
        self.python = os.path.expanduser(python) if python else sys.executable
        self.start_timeout_ms, self.margin_ms = int(start_timeout_ms), int(margin_ms)
        self._path = [str(p) for p in path]
        self._process: subprocess.Popen | None = None
        self._stderr: Any = None
        self._buffer = b""
        self._owed = 0  # answers not yet read: more than one while a call interrupted earlier left one
        self._lock = threading.RLock()  # calls and shutdown, from the loop and the watchdog thread
        self._ended = False  # shut down: no new child is started behind the adapter's back
        self.hello: dict = {}  # the child's first answer: pid, python and protobuf versions
        self.dead_reason = ""

    @property
    def pid(self) -> int | None:
        """The child's process id (None before the first call)."""
        return None if self._process is None else self._process.pid

    def start(self) -> None:
        """Start the child and wait until it has imported ``kortex_api``; ``LinkError`` (kind
        ``not_installed`` or ``dead``) naming the interpreter otherwise."""
        env = dict(os.environ)
        if self._path:
            env["PYTHONPATH"] = os.pathsep.join(self._path + [env.get("PYTHONPATH", "")]).rstrip(
                os.pathsep)
        self._stderr = tempfile.TemporaryFile()
        try:
            self._process = subprocess.Popen(
                [self.python, "-c", _BOOT, str(VENDOR_LINK)], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=self._stderr, env=env, close_fds=True,
                start_new_session=True)  # Ctrl-C at the terminal reaches the adapter, not the child
        except OSError as error:
            raise LinkError("dead", f"cannot start the kortex_api process with kortex.python "
                                    f"{self.python!r}: {error.strerror}") from None
        self._buffer, self.dead_reason, self._owed = b"", "", 0
        hello = self._receive(self.start_timeout_ms, "start-up")
        if "error" in hello:
            self.shutdown()
            raise LinkError(hello["error"], f"{hello.get('message', '')} (kortex.python "
                                            f"{self.python!r})")
        self.hello = hello

    def call(self, method: str, **args: Any) -> Any:
        """``method(**args)`` in the child (``args`` must hold ``timeout_ms``); its answer."""
        with self._lock:
            if self._ended:
                raise LinkError("dead", f"{method}: the kortex_api process was ended "
                                        f"({self.dead_reason or 'shut down'})")
            if self._process is None or self._process.poll() is not None:
                if self._process is not None:
                    raise self._died("before " + method)
                self.start()
            timeout_ms = int(args.get("timeout_ms", 0))
            line = json.dumps({"method": method, "args": args}) + "\n"
            self._owed += 1  # answers the child owes, this call's included
            try:
                assert self._process is not None and self._process.stdin is not None
                self._process.stdin.write(line.encode())
                self._process.stdin.flush()
            except (BrokenPipeError, OSError):
                raise self._died(method) from None
            while self._owed > 1:  # a call interrupted before its answer (Ctrl-C): drop that answer
                self._receive(timeout_ms + self.margin_ms, f"{method} (an earlier call's answer)")
                self._owed -= 1
            answer = self._receive(timeout_ms + self.margin_ms, method)
            self._owed -= 1
        if "error" in answer:
            raise LinkError(answer["error"], answer.get("message", ""))
        return answer.get("result")

    def _receive(self, limit_ms: int, what: str) -> dict:
        """The next answer line, within ``limit_ms``; else the child is killed (hung)."""
        process = self._process
        assert process is not None and process.stdout is not None
        fd = process.stdout.fileno()
        deadline = time.monotonic() + limit_ms / 1e3
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            ready = select.select([fd], [], [], max(0.0, left))[0] if left > 0 else []
            if not ready:
                self._kill()
                self.dead_reason = (f"the kortex_api process (pid {process.pid}) did not answer "
                                    f"{what} within {limit_ms} ms: killed")
                raise LinkError("dead", self.dead_reason)
            chunk = os.read(fd, 65536)
            if not chunk:
                raise self._died(what)
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        try:
            answer = json.loads(line)
        except ValueError:
            answer = None
        if not isinstance(answer, dict):
            self._kill()
            self.dead_reason = (f"the kortex_api process (pid {process.pid}) answered {what} with "
                                f"something that is not an answer ({line[:80]!r}): killed")
            raise LinkError("dead", self.dead_reason)
        return answer

    def _died(self, what: str) -> LinkError:
        process = self._process
        assert process is not None
        try:
            code = process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            self._kill()
            code = process.returncode
        tail = ""
        if self._stderr is not None:
            self._stderr.seek(0)
            lines = self._stderr.read().decode(errors="replace").strip().splitlines()
            tail = f": {lines[-1]}" if lines else ""
        self.dead_reason = (f"the kortex_api process (pid {process.pid}) exited with code {code} "
                            f"during {what}{tail}")
        return LinkError("dead", self.dead_reason)

    def _kill(self) -> None:
        if self._process is not None and self._process.poll() is None:
            self._process.kill()
            self._process.wait(timeout=5.0)

    def shutdown(self) -> None:
        """Ask the child to exit (then kill it if it does not); idempotent. Waits for a call in
        flight on another thread (at most its timeout plus the margin)."""
        with self._lock:
            self._shutdown()

    def _shutdown(self) -> None:
        self._ended = True
        process = self._process
        if process is None:
            return
        if process.poll() is None:
            try:
                assert process.stdin is not None
                process.stdin.write(b'{"method": "exit"}\n')
                process.stdin.flush()
                process.wait(timeout=2.0)
            except (OSError, subprocess.TimeoutExpired):
                self._kill()
        for stream in (process.stdin, process.stdout):
            if stream is not None:
                stream.close()
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
        self._process = None
