"""Run an emulated :class:`~ament_formation.core.serial.motor_board.MotorBoard` on the master
side of a pseudo-terminal, so that the bridge (or any serial program) opens the slave side like a
USB
serial port.

The runner keeps a stable path (a symlink, ``link_path``) to the current slave device: closing
the port removes it and the pty, reopening creates a new pty and points the symlink at it — what
unplugging and replugging a USB adapter looks like to the bridge. Fault injection (drop, corrupt,
delay bytes) applies per direction. Drive it with ``step()`` from your own loop or timer, or with
``start()``, which runs a thread that waits on the pty with ``select``.
"""

from __future__ import annotations

import os
from pathlib import Path
import select
import threading
import time
import tty
from typing import Callable

import numpy as np

from ament_formation.core.serial.byte_faults import ByteFaults, FaultSpec
from ament_formation.core.serial.motor_board import MotorBoard


class PtyBoard:
    """A motor board on a pty.

    Parameters
    ----------
    board : MotorBoard
        The emulated board (its times are ``clock()`` values).
    link_path : path, optional
        Stable symlink to the slave device; without it ``port`` is the /dev/pts/N name.
    rx_faults, tx_faults : FaultSpec
        Faults on bytes host -> board and board -> host.
    rng : numpy Generator for the faults; clock : monotonic time source [s].
    """

    def __init__(
        self,
        board: MotorBoard,
        link_path: str | Path | None = None,
        rx_faults: FaultSpec = FaultSpec(),
        tx_faults: FaultSpec = FaultSpec(),
        rng: np.random.Generator | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.board = board
        self.link_path = Path(link_path) if link_path is not None else None
        rng = rng if rng is not None else np.random.default_rng(0)
        self.rx = ByteFaults(rx_faults, rng)
        self.tx = ByteFaults(tx_faults, rng)
        self.clock = clock
        self.lock = threading.RLock()
        self.tx_overflow_bytes = 0
        self.bytes_in = 0
        self.bytes_out = 0
        self._master: int | None = None
        self._slave: int | None = None
        self.slave_name: str | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()

    # -- port ----------------------------------------------------------------------------------
    @property
    def port(self) -> str:
        """Path the host should open."""
        if self.link_path is not None:
            return str(self.link_path)
        if self.slave_name is None:
            raise RuntimeError('PtyBoard: port is closed')
        return self.slave_name

    @property
    def is_open(self) -> bool:
        return self._master is not None

    def open(self) -> str:  # noqa: A003
        """Create the pty (and the symlink); return the port path."""
        with self.lock:
            if self._master is not None:
                return self.port
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no line discipline: a clean 8-bit channel
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.slave_name = os.ttyname(slave)
            if self.link_path is not None:
                tmp = self.link_path.with_name(self.link_path.name + '.tmp')
                if tmp.is_symlink() or tmp.exists():
                    tmp.unlink()
                tmp.symlink_to(self.slave_name)
                os.replace(tmp, self.link_path)
        self._wake()
        return self.port

    def close_port(self) -> None:
        """Make the port disappear: remove the symlink, close both pty ends (the host gets EIO)."""
        with self.lock:
            if self.link_path is not None and self.link_path.is_symlink():
                self.link_path.unlink()
            for fd in (self._master, self._slave):
                if fd is not None:
                    os.close(fd)
            self._master = self._slave = None
            self.slave_name = None
            self.rx.clear()
            self.tx.clear()
            self.board.decoder.reset()
        self._wake()

    # -- running -------------------------------------------------------------------------------
    def step(self, now_s: float | None = None) -> None:
        """Move bytes both ways and advance the board to ``now_s`` (default ``clock()``)."""
        with self.lock:
            now_s = self.clock() if now_s is None else now_s
            if self._master is not None:
                data = b''
                try:
                    data = os.read(self._master, 4096)
                except (BlockingIOError, InterruptedError):
                    pass
                except OSError:  # EIO: no slave reader yet on some kernels
                    pass
                self.bytes_in += len(data)
                data = self.rx.pass_bytes(data, now_s)
                if data:
                    self.board.receive(data, now_s)
            self.board.step(now_s)
            out = self.tx.pass_bytes(self.board.take_output(), now_s)
            if self._master is not None and out:
                try:
                    n = os.write(self._master, out)
                except (BlockingIOError, OSError):
                    n = 0
                self.bytes_out += n
                self.tx_overflow_bytes += len(out) - n  # nobody reading: bytes fall on the floor

    def start(self, step_period_s: float = 0.001) -> None:
        """Run ``step`` in a daemon thread until ``stop()``: wakes on input or every
        ``step_period_s``.
        """
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._run, args=(step_period_s,), name='pty_board', daemon=True
        )
        self._thread.start()

    def _run(self, step_period_s: float) -> None:
        while not self._stop.is_set():
            fds = [self._wake_r] + ([self._master] if self._master is not None else [])
            try:
                ready, _, _ = select.select(fds, [], [], step_period_s)
            except (OSError, ValueError):  # the port was closed under us
                ready = []
            if self._wake_r in ready:
                os.read(self._wake_r, 64)
            self.step()

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b'x')
        except OSError:
            pass

    def stop(self) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._wake()
        self._thread.join(timeout=2.0)
        self._thread = None

    def close(self) -> None:
        """Stop the thread, remove the port, release the wake-up pipe."""
        self.stop()
        self.close_port()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> 'PtyBoard':
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PtyBoardGroup:
    """Run the ``step`` of several :class:`PtyBoard` from ONE thread (instead of one thread each).

    The thread waits with ``select`` on every open pty and wake-up pipe; a board is stepped when
    its host wrote bytes, and every board is stepped at least every ``step_period_s``. One thread
    for N boards keeps the wake-ups of a many-robot world at 1 / step_period_s + the command rate
    instead of N times that.
    """

    def __init__(self, boards: list[PtyBoard], step_period_s: float = 0.005) -> None:
        if not step_period_s > 0:
            raise ValueError(f'step_period_s: must be > 0 s (got {step_period_s!r})')
        self.boards = list(boards)
        self.step_period_s = float(step_period_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name='pty_boards', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_all = time.monotonic()
        while not self._stop.is_set():
            owner: dict[int, PtyBoard] = {}
            for b in self.boards:
                owner[b._wake_r] = b
                if b._master is not None:
                    owner[b._master] = b
            timeout = max(0.0, next_all - time.monotonic())
            try:
                ready, _, _ = select.select(list(owner), [], [], timeout)
            except (OSError, ValueError):  # a port was closed under us
                ready = []
            due = set()
            for fd in ready:
                b = owner[fd]
                if fd == b._wake_r:
                    try:
                        os.read(fd, 64)
                    except OSError:
                        pass
                due.add(id(b))
            now = time.monotonic()
            every = now >= next_all
            if every:
                next_all = max(next_all + self.step_period_s, now)
            for b in self.boards:
                if every or id(b) in due:
                    b.step()

    def stop(self) -> None:
        if self._thread is None:
            return
        self._stop.set()
        for b in self.boards:
            b._wake()
        self._thread.join(timeout=2.0)
        self._thread = None
