"""Frames from a camera, a video file or a network stream (cv2.VideoCapture), grabbed in a thread.

``source`` forms (:func:`parse_source`):

| given | kind | opened with |
|---|---|---|
| ``0``, ``"2"`` (a device index) | device | V4L2 (``/dev/video<N>``) |
| ``"/dev/video0"``, ``"/dev/v4l/by-id/…"`` | device | V4L2 |
| ``"http://…"``, ``"rtsp://…"``, any ``scheme://`` | stream | FFmpeg, open/read timeouts |
| anything else | file | FFmpeg, played at the file's frame rate |

:class:`FrameGrabber` keeps only the newest frame (mono8) with the time it was grabbed, so a slow
consumer never sees a stale queue. It never gives up on a live source: a device or stream that
fails (unplugged, server gone, no data for ``read_timeout_s``) is released and reopened with
exponential backoff, and frames resume by themselves. A video file that ends is either replayed
(``loop``) or marks the grabber ``ended``.

OpenCV's and FFmpeg's own console messages are silenced (set ``OPENCV_LOG_LEVEL`` /
``OPENCV_FFMPEG_LOGLEVEL`` in the environment to see them): the caller reports failures in its
own words (:func:`open_problem`).
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import re
import sys
import threading
import time
from typing import Any, Callable

os.environ.setdefault(
    'OPENCV_FFMPEG_LOGLEVEL', '-8'
)  # AV_LOG_QUIET, read when FFmpeg is first used

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from ament_formation.core.errors import ConfigError  # noqa: E402

if 'OPENCV_LOG_LEVEL' not in os.environ:
    _cv_logging = getattr(getattr(cv2, 'utils', None), 'logging', None)  # OpenCV 4.6: none
    if _cv_logging is not None:
        _cv_logging.setLogLevel(_cv_logging.LOG_LEVEL_SILENT)
    else:
        cv2.setLogLevel(0)  # 0: silent (the OpenCV 4.6 Python API)

DEVICE, FILE, STREAM = 'device', 'file', 'stream'
_SCHEME = re.compile(r'^[A-Za-z][A-Za-z0-9+.-]*://')
_LINUX = sys.platform.startswith('linux')


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``source``: ``kind`` (device, file, stream), ``target`` (device index or path,
    file path, URL) and ``text``, the value as given (for messages).
    """

    kind: str
    target: int | str
    text: str

    @property
    def device_path(self) -> str | None:
        """The device node of a device source (``/dev/video<N>`` for an index), else None."""
        if self.kind != DEVICE:
            return None
        return f'/dev/video{self.target}' if isinstance(self.target, int) else str(self.target)


def parse_source(value: Any) -> SourceSpec | None:
    """``source`` parameter → SourceSpec, or None for "" / None (no source: frames come by topic).

    Raises ConfigError naming ``source`` for values of another type (float, bool, list) or a
    negative device index.
    """
    if value is None or value == '':
        return None
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise ConfigError(
            f'expected a device index, a device path, a video file or a stream URL '
            f'(got {value!r})',
            'source',
        )
    if isinstance(value, int):
        if value < 0:
            raise ConfigError(f'a device index is >= 0 (got {value})', 'source')
        return SourceSpec(DEVICE, value, str(value))
    text = value.strip()
    if not text:
        return None
    if text.isdigit():
        return SourceSpec(DEVICE, int(text), text)
    if _SCHEME.match(text):
        return SourceSpec(STREAM, text, text)
    if text.startswith('/dev/'):
        return SourceSpec(DEVICE, text, text)
    return SourceSpec(FILE, str(Path(text).expanduser()), text)


def open_problem(spec: SourceSpec) -> str:
    """Why ``spec`` cannot be opened, in a few words (after :func:`open_capture` failed)."""
    if spec.kind == DEVICE:
        path = spec.device_path
        if _LINUX and not os.path.exists(path):
            return f'no such video device {path}'
        if _LINUX and not os.access(path, os.R_OK | os.W_OK):
            return f"no permission to open {path} (add the user to group 'video')"
        return f'cannot open {path} (busy, or not a video capture device)'
    if spec.kind == FILE:
        path = Path(spec.target)
        if not path.exists():
            return 'no such file'
        if not path.is_file():
            return 'not a file'
        return 'cannot read it as a video'
    return 'cannot open the stream (refused, unreachable, timed out or not a video)'


def open_capture(
    spec: SourceSpec,
    *,
    size_px: tuple[int, int] | None = None,
    fps_hz: float | None = None,
    open_timeout_s: float = 3.0,
    read_timeout_s: float = 1.0,
) -> cv2.VideoCapture | None:
    """An opened cv2.VideoCapture for ``spec``, or None.

    A device is asked for ``size_px`` (width, height) and ``fps_hz`` (best effort; the frames say
    what it delivers) and a one-frame driver queue; a stream gets the open and read timeouts, so a
    silent server makes ``grab()`` fail instead of blocking forever.
    """
    if spec.kind == DEVICE:
        cap = cv2.VideoCapture(spec.target, cv2.CAP_V4L2 if _LINUX else cv2.CAP_ANY)
        if cap.isOpened():
            if size_px is not None:
                cap.set(cv2.CAP_PROP_FRAME_WIDTH, float(size_px[0]))
                cap.set(cv2.CAP_PROP_FRAME_HEIGHT, float(size_px[1]))
            if fps_hz:
                cap.set(cv2.CAP_PROP_FPS, float(fps_hz))
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1.0)
    elif spec.kind == FILE:
        if not Path(spec.target).is_file():
            return None
        cap = cv2.VideoCapture(str(spec.target), cv2.CAP_FFMPEG)
    else:
        cap = cv2.VideoCapture(
            str(spec.target),
            cv2.CAP_FFMPEG,
            [
                cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
                int(open_timeout_s * 1000),
                cv2.CAP_PROP_READ_TIMEOUT_MSEC,
                int(read_timeout_s * 1000),
            ],
        )
    if not cap.isOpened():
        cap.release()
        return None
    return cap


class FrameGrabber(threading.Thread):
    """Grabs frames from ``spec`` in a daemon thread; :meth:`take` hands over the newest one.

    Parameters
    ----------
    spec : SourceSpec
    now : callable returning the capture stamp of a frame (called right after ``grab()``).
    loop : replay a video file when it ends.
    size_px, fps_hz : what to ask a device for (see :func:`open_capture`).
    backoff_s : (first, max) wait between reopen attempts [s]; doubles after each failure.
    opener : ``opener(spec) -> VideoCapture | None`` (tests inject failures through it).

    ``state`` is ``"closed"`` (never opened yet), ``"open"``, ``"lost"`` (was open, reopening)
    or ``"ended"`` (a file ran out without ``loop``). Counters: ``frames`` grabbed, ``errors``
    (failed retrieves), ``open_attempts`` failed since the last success, ``reopens`` (successful
    reopens after a loss). Monotonic times [s]: ``lost_since_s``, ``last_frame_s`` (the last frame,
    or when the source was opened if no frame came since).
    """

    def __init__(
        self,
        spec: SourceSpec,
        now: Callable[[], Any],
        *,
        loop: bool = False,
        size_px: tuple[int, int] | None = None,
        fps_hz: float | None = None,
        open_timeout_s: float = 3.0,
        read_timeout_s: float = 1.0,
        backoff_s: tuple[float, float] = (0.1, 2.0),
        opener: Callable[[SourceSpec], Any] | None = None,
    ) -> None:
        super().__init__(daemon=True, name='video_source')
        self.spec = spec
        self._now = now
        self._loop = loop
        self._backoff_s = backoff_s
        self._open = opener or (
            lambda s: open_capture(
                s,
                size_px=size_px,
                fps_hz=fps_hz,
                open_timeout_s=open_timeout_s,
                read_timeout_s=read_timeout_s,
            )
        )
        self._halt = threading.Event()
        self._lock = threading.Lock()
        self._latest: tuple[np.ndarray, Any] | None = None
        self._cap = None
        self.state = 'closed'
        self.frames = 0
        self.errors = 0
        self.open_attempts = 0
        self.reopens = 0
        self.lost_since_s: float | None = None
        self.last_frame_s = time.monotonic()
        self.frame_size_px: tuple[int, int] | None = None
        self.fps_hz = 0.0

    # ------------------------------------------------------------------ caller side
    def try_open(self) -> bool:
        """One synchronous open attempt (before :meth:`start`); True when the source is open."""
        return self._attempt_open()

    def take(self) -> tuple[np.ndarray, Any] | None:
        """The newest (frame (H, W) uint8, stamp) not taken yet, or None."""
        with self._lock:
            item, self._latest = self._latest, None
        return item

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop grabbing and release the source (waits up to ``timeout_s`` for the thread)."""
        self._halt.set()
        if self.is_alive():
            self.join(timeout=timeout_s)
        if not self.is_alive() and self._cap is not None:
            self._cap.release()
            self._cap = None

    # ------------------------------------------------------------------ thread
    def _attempt_open(self) -> bool:
        cap = self._open(self.spec)
        if cap is None:
            self.open_attempts += 1
            return False
        if self.state == 'lost':
            self.reopens += 1
        self._cap = cap
        self.open_attempts = 0
        self.lost_since_s = None
        self.last_frame_s = time.monotonic()  # silence is counted from here
        fps = cap.get(cv2.CAP_PROP_FPS)
        self.fps_hz = float(fps) if fps and 0.0 < fps < 1000.0 else 0.0
        self.state = 'open'
        return True

    def _lose(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        if self.state == 'open':
            self.lost_since_s = time.monotonic()
        self.state = 'lost'

    def run(self) -> None:
        backoff_s = self._backoff_s[0]
        while not self._halt.is_set():
            if self._cap is None:
                if self._attempt_open():
                    backoff_s = self._backoff_s[0]
                else:
                    self._halt.wait(backoff_s)
                    backoff_s = min(2.0 * backoff_s, self._backoff_s[1])
                    continue
            self._grab_until_failure()
            if self._halt.is_set():
                break
            if self.spec.kind == FILE:
                self._cap.release()
                self._cap = None
                if self._loop:
                    continue
                self.state = 'ended'
                return
            self._lose()
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _grab_until_failure(self) -> None:
        """Grab frames until the source fails (or a file ends, or :meth:`stop`)."""
        cap = self._cap
        # a file plays at its own frame rate, like a camera would (30 fps when it does not say):
        # frame n is due n periods after the start; frames already overdue by more than a period
        # are skipped, as a camera's frames are lost when nobody reads them
        period_s = (1.0 / (self.fps_hz or 30.0)) if self.spec.kind == FILE else 0.0
        start_s, n = time.monotonic(), 0
        failed_retrieves = 0
        while not self._halt.is_set():
            if period_s:
                delay_s = start_s + n * period_s - time.monotonic()
                if delay_s > 0.0:
                    self._halt.wait(delay_s)
                while delay_s < -period_s:  # behind: skip a frame
                    if not cap.grab():
                        return
                    n += 1
                    delay_s += period_s
                n += 1
            if not cap.grab():
                return
            stamp = self._now()
            ok, frame = cap.retrieve()
            if not ok or frame is None:
                self.errors += 1
                failed_retrieves += 1
                if failed_retrieves >= 30:  # a source that delivers nothing usable is lost
                    return
                continue
            failed_retrieves = 0
            if frame.ndim == 3:
                frame = cv2.cvtColor(
                    frame, cv2.COLOR_BGR2GRAY if frame.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
                )
            frame = np.ascontiguousarray(frame)
            with self._lock:
                self._latest = (frame, stamp)
            self.frames += 1
            self.last_frame_s = time.monotonic()
            self.frame_size_px = (frame.shape[1], frame.shape[0])
