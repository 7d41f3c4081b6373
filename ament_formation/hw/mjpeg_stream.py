"""A camera stream on the machine itself: frames served as MJPEG over HTTP
(``multipart/x-mixed-replace``, what IP cameras and ``mjpg-streamer`` serve), which the tracker
opens as ``source: http://127.0.0.1:<port>/stream.mjpg`` (hw/video_source.py, OpenCV's FFmpeg).

Used to exercise the tracker's stream source and its loss handling without a camera: tests and
benchmarks serve rendered frames, cut the stream (:meth:`MjpegServer.stop`) and bring it back on
the same port (:meth:`MjpegServer.start`). Binds 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
import socket
import threading
import time
from typing import Sequence

import cv2
import numpy as np

BOUNDARY = 'frame'


def encode_jpeg(frame: np.ndarray, quality: int = 90) -> bytes:
    """JPEG bytes of a mono8 or bgr8 frame."""
    ok, buf = cv2.imencode('.jpg', frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f'frame: cannot encode {frame.shape} {frame.dtype} as JPEG')
    return buf.tobytes()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True


class MjpegServer:
    """Serves the newest frame to every client as it arrives.

    Feed it with :meth:`publish` (e.g. from a ROS subscription), or give ``frames`` and ``fps_hz``
    to :meth:`play` them in a thread, forwards then backwards (ping-pong: no jump at the ends).
    ``frames_sent`` counts frames written to clients; ``clients`` is the number connected now.
    """

    def __init__(self, host: str = '127.0.0.1', port: int = 0, quality: int = 90) -> None:
        self.host = host
        self.port = port
        self.quality = quality
        self._cond = threading.Condition()
        self._jpeg: bytes | None = None
        self._seq = 0
        self._halt = threading.Event()
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None
        self._player: threading.Thread | None = None
        self.frames_sent = 0
        self.clients = 0

    @property
    def url(self) -> str:
        return f'http://{self.host}:{self.port}/stream.mjpg'

    # ------------------------------------------------------------------ frames
    def publish(self, frame: np.ndarray | bytes) -> None:
        """Make ``frame`` (an image, or JPEG bytes) the newest; every client gets it once."""
        jpeg = frame if isinstance(frame, bytes) else encode_jpeg(frame, self.quality)
        with self._cond:
            self._jpeg = jpeg
            self._seq += 1
            self._cond.notify_all()

    def play(self, frames: Sequence[np.ndarray], fps_hz: float) -> None:
        """Publish ``frames`` at ``fps_hz`` in a thread (ping-pong) until :meth:`close`."""
        jpegs = [encode_jpeg(f, self.quality) for f in frames]
        order = list(range(len(jpegs))) + list(range(len(jpegs) - 2, 0, -1))

        def run() -> None:
            k, next_s = 0, time.monotonic()
            while not self._stop_play.is_set():
                self.publish(jpegs[order[k % len(order)]])
                k += 1
                next_s += 1.0 / fps_hz
                self._stop_play.wait(max(next_s - time.monotonic(), 0.0))

        self._stop_play = threading.Event()
        self._player = threading.Thread(target=run, daemon=True, name='mjpeg_player')
        self._player.start()

    # ------------------------------------------------------------------ serving
    def start(self) -> str:
        """Listen (on the same port again after :meth:`stop`) and return the stream URL."""
        owner = self

        class Handler(BaseHTTPRequestHandler):

            def do_GET(self) -> None:  # noqa: N802 - http.server API
                self.send_response(200)
                self.send_header('Content-Type', f'multipart/x-mixed-replace; boundary={BOUNDARY}')
                self.send_header('Cache-Control', 'no-cache')
                self.end_headers()
                owner.clients += 1
                seq = 0
                try:
                    while not owner._halt.is_set():
                        with owner._cond:
                            owner._cond.wait_for(
                                lambda: owner._seq != seq or owner._halt.is_set(), 0.1
                            )
                            if owner._halt.is_set() or owner._seq == seq or owner._jpeg is None:
                                continue
                            seq, jpeg = owner._seq, owner._jpeg
                        self.wfile.write(
                            f'--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n'
                            f'Content-Length: {len(jpeg)}\r\n\r\n'.encode()
                            + jpeg
                            + b'\r\n'
                        )
                        owner.frames_sent += 1
                except (BrokenPipeError, ConnectionResetError):
                    pass
                finally:
                    owner.clients -= 1

            def log_message(self, *args) -> None:
                pass

        self._halt.clear()
        self._server = _Server((self.host, self.port), Handler)
        self.port = self._server.server_address[1]
        self._thread = threading.Thread(
            target=self._server.serve_forever,
            kwargs={'poll_interval': 0.05},
            daemon=True,
            name='mjpeg_server',
        )
        self._thread.start()
        return self.url

    def stop(self) -> None:
        """Cut the stream: close the listening socket and every client connection."""
        if self._server is None:
            return
        self._halt.set()
        with self._cond:
            self._cond.notify_all()
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=2.0)
        self._server = None
        deadline = time.monotonic() + 2.0
        while self.clients and time.monotonic() < deadline:  # handlers see the halt within 0.1 s
            time.sleep(0.01)

    def close(self) -> None:
        """Stop serving and playing."""
        if self._player is not None:
            self._stop_play.set()
            self._player.join(timeout=2.0)
            self._player = None
        self.stop()


def free_port(host: str = '127.0.0.1') -> int:
    """A TCP port free on ``host`` now."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]
