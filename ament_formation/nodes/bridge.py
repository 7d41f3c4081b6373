"""formation_bridge: the serial bridge between a robot's controller and its motor board.

Contract (namespace ``robot_<id>``; protocol: docs/serial-protocol.md)

Topics (type; QoS; direction):

- wheel_torque: sensor_msgs/JointState (effort [left, right] N·m); QOS_CONTROL; subscribed
- wheel_state: sensor_msgs/JointState (position rad, velocity rad/s, [left, right]); QOS_CONTROL;
  published per TELEMETRY
- /diagnostics: diagnostic_msgs/DiagnosticArray: "formation_bridge: robot_<id> serial link"
  (up OK, connecting WARN, down/mismatch ERROR), "... robot_<id> serial poll" (stalls, WARN);
  hardware_id robot_<id> (the port when not in a robot namespace); QOS_DIAGNOSTICS; every
  diagnostics_period_s and at once on a link state change

Parameters (core.serial.serial_link.LinkParams): port (path or pyserial URL, "/dev/ttyACM0"),
baud_rate (115200), torque_limit_nm (0.15 N·m), watchdog_s (0.2 s, sent to the board),
input_timeout_s (0.2 s: older wheel_torque -> STOP: the board brakes), command_rate_hz (100 Hz),
telemetry_period_s (0.01 s), ack_timeout_s (0.006 s), link_timeout_s (0.5 s),
hello_retry_s (0.2 s), heartbeat_period_s (1 s), reconnect_initial_s (0.05 s) doubling to
reconnect_max_s (0.5 s), poll_rate_hz (500 Hz), diagnostics_period_s (1 s), wait_for_port (false).

A port that cannot be opened at start ends the process with one line on stderr naming it (exit
code 2), unless ``wait_for_port`` is true: then the bridge waits for it, reopening with backoff.

The port is read and written only non-blocking, from a timer: the executor never blocks. Safety
(docs/design.md §7): NaN/inf inputs are rejected and counted, torques clamped, stale input -> STOP
(the
board brakes to rest), a vanished port is reopened with backoff, STOP is sent on shutdown.
"""

from __future__ import annotations

import os
import sys
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState
import serial

try:
    from serial.serialposix import Serial as _PosixSerial
except ImportError:  # not a POSIX system: pyserial's read for every port
    _PosixSerial = None

from ament_formation.core.errors import ConfigError
from ament_formation.core.serial import serial_link as sl
from ament_formation.ros import diagnostics as diag
from ament_formation.ros.executors import run_node
from ament_formation.ros.listeners import Listeners
from ament_formation.ros.messages import stamp_from_ns, wheel_state
from ament_formation.ros.params import declare_dataclass
from ament_formation.ros.qos import QOS_CONTROL
from ament_formation.ros.wheels import torques_from_joint_state


def _open_error(err: Exception) -> str:
    """The reason of an open failure without pyserial's repetitions ("[Errno 2] could not open
    port X: [Errno 2] No such file or directory: 'X'" -> "No such file or directory").
    """
    errno = getattr(err, 'errno', None)
    if errno:
        return os.strerror(errno)
    return str(err).splitlines()[0] if str(err) else type(err).__name__


def open_port(url: str, baud_rate: int) -> serial.SerialBase:
    """Open ``url`` non-blocking without touching DTR/RTS flow control (works on ptys)."""
    port = serial.serial_for_url(
        url,
        baudrate=baud_rate,
        timeout=0,
        write_timeout=0,
        rtscts=False,
        dsrdtr=False,
        xonxoff=False,
        do_not_open=True,
    )
    port.open()
    return port


class BridgeNode(Node):
    """Thin shell around :class:`~ament_formation.core.serial.serial_link.LinkHost`
    (the protocol logic).
    """

    def __init__(
        self,
        *,
        context=None,
        clock=time.monotonic,
        poll_timer: bool = True,
        torque_topic: bool = True,
        **kwargs,
    ) -> None:
        """``poll_timer=False``: no poll timer of its own; the owner calls :meth:`poll` at
        ``poll_rate_hz`` (nodes/team.py). ``torque_topic=False``: no wheel_torque subscription;
        the owner's controller calls :meth:`command` (a team: the controller in the same process).
        ``telemetry_sinks``: callables ``(position_rad, velocity_radps, stamp_s)`` given every
        wheel sample (pairs of floats, left and right); with a sink, wheel_state is published only
        while someone subscribes.
        """
        super().__init__('formation_bridge', context=context, **kwargs)
        self.params = declare_dataclass(self, sl.LinkParams)
        self.link = sl.LinkHost(self.params)
        self._mono = clock
        self._now_ns = diag.clock_ns(self)  # the node's clock [ns] (wheel sample stamps)
        self._port: serial.SerialBase | None = None
        self._backoff = sl.Backoff(self.params.reconnect_initial_s, self.params.reconnect_max_s)
        self._next_open_s = 0.0
        self._last_error = ''
        self._rx_frames_at_diag = (clock(), 0)
        self.link_up_since_s: float | None = None
        if not self.params.wait_for_port:  # a port missing at start is a configuration error
            try:
                self._port = open_port(self.params.port, self.params.baud_rate)
            except (serial.SerialException, OSError, ValueError) as err:
                name = self.get_fully_qualified_name()
                Node.destroy_node(self)
                raise ConfigError(
                    f'cannot open {self.params.port}: {_open_error(err)} (wait_for_port:=true '
                    'waits for it)',
                    'port',
                    name,
                ) from None
            self._write(self.link.connected(clock()))
        self._pub_state = self.create_publisher(JointState, 'wheel_state', QOS_CONTROL)
        self._state_heard = Listeners(self._pub_state)  # matched subscriptions (0.1 s old at most)
        self.diag = diag.Diagnostics(self, self.params.diagnostics_period_s)
        robot = diag.robot_of_namespace(self.get_namespace())
        self.diag.add(
            f'{robot} serial link' if robot else 'serial link',
            self._link_status,
            hardware_id=robot or self.params.port,
        )
        self.poll_watch = (
            self.diag.watch(
                f'{robot} serial poll' if robot else 'serial poll',
                1.0 / self.params.poll_rate_hz,
                hardware_id=robot or self.params.port,
            )
            if poll_timer
            else None
        )  # in a team, the team watches its poll timer
        self._link_state_seen = self.link.state
        self.telemetry_sinks: list = []
        if torque_topic:
            self.create_subscription(JointState, 'wheel_torque', self._on_torque, QOS_CONTROL)
        if poll_timer:
            self.create_timer(1.0 / self.params.poll_rate_hz, self._timed_poll)

    # -- callbacks -----------------------------------------------------------------------------
    def _on_torque(self, msg: JointState) -> None:
        self.command(torques_from_joint_state(msg))

    def command(self, torques_nm: tuple[float, float] | None) -> bool:
        """Take (left, right) wheel torques [N m] as the new input and send them to the board now
        (what a wheel_torque message does). False (counted, logged) for anything but two finite
        values.
        """
        now = self._mono()
        if not self.link.set_input(torques_nm, now):
            self.get_logger().warn(
                'wheel_torque rejected (need 2 finite efforts)', throttle_duration_sec=1.0
            )
            return False
        self._write(self.link.command_now(now))
        return True

    def poll(self) -> None:
        """Read the port, publish telemetry, write what the link has to send
        (see :meth:`_poll`).
        """
        self._poll()

    def _timed_poll(self) -> None:
        self.poll_watch.tick()
        self._poll()

    def _poll(self) -> None:
        now = self._mono()
        port = self._port
        if port is None:
            if now >= self._next_open_s:
                self._try_open(now)
            return
        try:  # ask the driver first: an empty poll is one ioctl instead of pyserial's select loop
            waiting = port.in_waiting
            data = self._read(port, min(waiting, 4096)) if waiting else b''
        except (serial.SerialException, OSError) as err:
            self._lost(now, f'read: {err}')
            return
        link = self.link
        if data:
            samples, answer = link.receive(data, now)
            if samples:
                self._samples(samples)
            out = answer + link.poll(now)
        else:
            out = link.poll(now)
        if out:
            self._write(out)
        state = link.state
        if state == sl.VERSION_MISMATCH and self._last_error != link.version_mismatch_text():
            self._last_error = link.version_mismatch_text()  # once per connection
            self.get_logger().error(f'{self.params.port}: {self._last_error}')
        if state == sl.UP and self.link_up_since_s is None:
            self.link_up_since_s = now
            self.get_logger().info(f'link up on {self.params.port}')
        if self._port is not None and link.timed_out(now):
            self._lost(now, 'no valid frame from the board')
        if link.state != self._link_state_seen:  # published when it happens
            self._link_state_seen = link.state
            self.diag.changed()

    def _samples(self, samples: list) -> None:
        """Hand the wheel samples of one read to the sinks and publish them on wheel_state (with
        sinks: while someone subscribes). Stamp: the node's clock when they are handed on.
        """
        sinks = self.telemetry_sinks
        for s in samples:
            stamp_ns = self._now_ns()
            for sink in sinks:
                sink(s.position_rad, s.velocity_radps, stamp_ns * 1e-9)
            if not sinks or self._state_heard():
                self._pub_state.publish(
                    wheel_state(s.position_rad, s.velocity_radps, stamp_from_ns(stamp_ns))
                )

    @staticmethod
    def _read(port, size: int) -> bytes:
        """Up to ``size`` bytes the driver said are waiting: on a POSIX port one os.read of its
        descriptor (what pyserial's read does after a select that in_waiting made redundant; its
        errors as pyserial raises them), on any other port (pyserial URLs) pyserial's read.
        """
        if type(port) is not _PosixSerial or not port.is_open:
            return port.read(size)
        try:
            data = os.read(port.fd, size)
        except (BlockingIOError, InterruptedError):
            return b''
        except OSError as err:
            raise serial.SerialException(f'read failed: {err}') from None
        if not data:  # as pyserial: a disconnected device reads as ready with nothing to read
            raise serial.SerialException(
                'device reports readiness to read but returned no data '
                '(device disconnected or multiple access on port?)'
            )
        return data

    def _try_open(self, now: float) -> None:
        try:
            self._port = open_port(self.params.port, self.params.baud_rate)
        except (serial.SerialException, OSError, ValueError) as err:
            self._last_error = f'open: {err}'
            self._next_open_s = now + self._backoff.next_delay()
            self.get_logger().warn(
                f'cannot open {self.params.port}: {err}', throttle_duration_sec=2.0
            )
            return
        self._backoff.reset()
        self._write(self.link.connected(now))

    def _write(self, data: bytes) -> None:
        port = self._port
        if not data or port is None:
            return
        try:
            if type(port) is _PosixSerial and port.is_open and port.write_timeout == 0:
                # what pyserial's non-blocking write does: one os.write (it retries one that
                # would block, as does its write below)
                try:
                    os.write(port.fd, data)
                    return
                except (BlockingIOError, InterruptedError):
                    pass
                except OSError as err:
                    raise serial.SerialException(f'write failed: {err}') from None
            port.write(data)
        except (serial.SerialException, OSError) as err:
            self._lost(self._mono(), f'write: {err}')

    def _lost(self, now: float, why: str) -> None:
        self._last_error = why
        self.get_logger().warn(f'serial link lost ({why}); reopening', throttle_duration_sec=1.0)
        self._close_port()
        self.link.disconnected()
        self.link_up_since_s = None
        self._next_open_s = now + self._backoff.next_delay()
        self._link_state_seen = self.link.state
        self.diag.changed()  # a lost link is published when it happens

    def _close_port(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None

    # -- diagnostics ---------------------------------------------------------------------------
    def diagnostics_values(self) -> dict:
        now = self._mono()
        t0, n0 = self._rx_frames_at_diag
        rx = self.link.stats['rx_frames']
        self._rx_frames_at_diag = (now, rx)
        p50, p99 = self.link.rtt_percentiles_s()
        values = {
            'link': self.link.state,
            'port': self.params.port,
            'rx_frames_per_s': (rx - n0) / max(now - t0, 1e-9),
        }
        values.update(self.link.stats)
        values.update({f'host_rejected_{k}': v for k, v in self.link.decoder.rejected.items()})
        values.update(
            {
                'rtt_p50_ms': p50 * 1e3,
                'rtt_p99_ms': p99 * 1e3,
                'board_flags': self.link.flags,
                'last_error': self._last_error,
            }
        )
        st = self.link.board_status
        if st is not None:
            values.update(
                {
                    'board_crc_errors': st.crc_errors,
                    'board_frame_errors': st.frame_errors,
                    'board_type_errors': st.type_errors,
                    'board_rx_gaps': st.rx_gaps,
                    'board_watchdog_trips': st.watchdog_trips,
                }
            )
        return values

    def _link_status(self) -> tuple[int, str, dict]:
        values = self.diagnostics_values()
        state = self.link.state
        level = (
            diag.OK
            if state == sl.UP
            else diag.WARN
            if state in (sl.HANDSHAKE, sl.CONFIGURING)
            else diag.ERROR
        )
        message = {
            'up': 'link up',
            'down': 'link down',
            'version_mismatch': self.link.version_mismatch_text(),
        }.get(state, 'connecting')
        return level, message, values

    # -- shutdown ------------------------------------------------------------------------------
    def shutdown(self) -> None:
        """Send STOP (three frames: the board brakes the wheels to rest) and close the port."""
        if self._port is not None:
            self._write(self.link.stop_commands(3))
            try:
                if self._port is not None:
                    self._port.flush()
            except (serial.SerialException, OSError):
                pass
        self._close_port()

    def destroy_node(self) -> None:
        self.shutdown()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node('formation_bridge', BridgeNode, args)


if __name__ == '__main__':
    sys.exit(main())
