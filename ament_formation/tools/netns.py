"""A lab network made of Linux network namespaces (`formation multihost`, docs/multi-machine.md).

One namespace per host: the camera PC (``af_cam_<run>``) and one per robot (``af_r<id>_<run>``),
each with a single interface ``eth0`` on 10.77.0.0/24 (camera .1, robot ``id`` .10+id) and its own
loopback; and a switch namespace (``af_sw_<run>``) holding a bridge ``br0`` with one veth port per
host (``cam``, ``r<id>``). Nothing is created outside these namespaces: each veth pair is made in
the switch namespace with its host end moved straight into the host's namespace, so the
machine's own interfaces, addresses and routes are never touched. Multicast (DDS discovery) is
routed to ``eth0`` in every host; the bridge floods it (no IGMP snooping).

    net = LabNetwork([0, 1], rate='2mbit')   # nothing exists yet
    net.build()                              # namespaces, bridge, veths, addresses
    net.set_link(1, up=False)                # robot 1's cable pulled (switch side), then True
    net.counters()                           # {port: (bytes from the host, bytes to the host)}
    net.destroy()                            # every namespace (and with them bridge and veths)

Needs root (CAP_NET_ADMIN, CAP_SYS_ADMIN) and iproute2 (``ip``, ``tc`` for ``rate``).
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import subprocess

PREFIX = 'af_'
SUBNET = '10.77.0'  # /24
CAMERA_ADDRESS = f'{SUBNET}.1'
_RATE_RE = re.compile(r'^\d+(\.\d+)?(bit|kbit|mbit|gbit|bps|kbps|mbps)$')


class NetnsError(RuntimeError):
    """An ``ip``/``tc`` command failed (its command line and stderr in the message)."""


def robot_address(rid: int) -> str:
    return f'{SUBNET}.{10 + int(rid)}'


def unavailable_reason() -> str | None:
    """Why namespaces cannot be built here (not root, no ``ip`` or no ``ip netns``), or None."""
    if os.geteuid() != 0:
        return 'needs root (network namespaces: CAP_NET_ADMIN and CAP_SYS_ADMIN)'
    if shutil.which('ip') is None:
        return 'iproute2 `ip` not found'
    probe = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True)
    if probe.returncode != 0:
        return f'`ip netns` unavailable: {probe.stderr.strip()}'
    return None


def valid_rate(rate: str) -> bool:
    """A tc rate such as ``500kbit``, ``2mbit`` or ``100kbps``."""
    return bool(_RATE_RE.match(rate))


def list_namespaces(prefix: str = PREFIX) -> list[str]:
    out = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(prefix)]


class LabNetwork:
    """See the module docstring. ``suffix``: run-unique part of every name (default: random)."""

    def __init__(self, robot_ids, suffix: str | None = None, rate: str | None = None):
        if rate is not None and not valid_rate(rate):
            raise ValueError(f'rate: expected a tc rate such as 2mbit or 500kbit (got {rate!r})')
        self.suffix = suffix or f'{os.getpid() % 10000}{secrets.token_hex(2)}'
        self.robot_ids = [int(r) for r in robot_ids]
        self.rate = rate
        self.switch = f'{PREFIX}sw_{self.suffix}'
        self.camera = f'{PREFIX}cam_{self.suffix}'
        self.robots = {rid: f'{PREFIX}r{rid}_{self.suffix}' for rid in self.robot_ids}
        self.ports = {'camera': 'cam', **{rid: f'r{rid}' for rid in self.robot_ids}}
        self.made: list[str] = []  # namespaces created (destroy() deletes exactly these)

    # ------------------------------------------------------------------ helpers
    @property
    def hosts(self) -> dict:
        """{'camera' | robot id: namespace name}."""
        return {'camera': self.camera, **self.robots}

    def address(self, host) -> str:
        return CAMERA_ADDRESS if host == 'camera' else robot_address(host)

    @staticmethod
    def _run(*argv: str) -> str:
        proc = subprocess.run(list(argv), capture_output=True, text=True)
        if proc.returncode != 0:
            raise NetnsError(f'{" ".join(argv)}: {proc.stderr.strip() or proc.returncode}')
        return proc.stdout

    def _ip(self, ns: str, *args: str) -> str:
        return self._run('ip', '-n', ns, *args)

    def exec_prefix(self, host) -> list[str]:
        """Command prefix that runs a program inside ``host``'s namespace."""
        return ['ip', 'netns', 'exec', self.hosts[host]]

    # ------------------------------------------------------------------ build / destroy
    def build(self) -> None:
        """Create the namespaces, the bridge, one veth per host, addresses and routes. On failure
        whatever was made is removed again before the error propagates.
        """
        try:
            for ns in [self.switch, *self.hosts.values()]:
                self._run('ip', 'netns', 'add', ns)
                self.made.append(ns)
                self._ip(ns, 'link', 'set', 'lo', 'up')
                # IPv4 only: no IPv6 neighbour discovery noise in the link counters
                self._run('ip', 'netns', 'exec', ns, 'sysctl', '-qw',
                          'net.ipv6.conf.all.disable_ipv6=1',
                          'net.ipv6.conf.default.disable_ipv6=1')  # fmt: skip
            self._ip(
                self.switch, 'link', 'add', 'br0', 'type', 'bridge', 'mcast_snooping', '0',
                'stp_state', '0',
            )  # fmt: skip
            self._ip(self.switch, 'link', 'set', 'br0', 'up')
            for host, ns in self.hosts.items():
                port = self.ports[host]
                self._ip(self.switch, 'link', 'add', port, 'type', 'veth', 'peer', 'name', 'eth0',
                         'netns', ns)  # fmt: skip
                self._ip(self.switch, 'link', 'set', port, 'master', 'br0')
                self._ip(self.switch, 'link', 'set', port, 'up')
                self._ip(ns, 'addr', 'add', f'{self.address(host)}/24', 'dev', 'eth0')
                self._ip(ns, 'link', 'set', 'eth0', 'up')
                self._ip(ns, 'route', 'add', '224.0.0.0/4', 'dev', 'eth0')  # DDS discovery
                if self.rate is not None and host != 'camera':
                    self._limit(self.switch, port)  # to the robot
                    self._limit(ns, 'eth0')  # from the robot
        except BaseException:
            self.destroy()
            raise

    def _limit(self, ns: str, dev: str) -> None:
        # burst: at least one full-size frame and 10 ms at the rate; queue: 50 ms at the rate
        self._run('tc', '-n', ns, 'qdisc', 'add', 'dev', dev, 'root', 'tbf', 'rate', self.rate,
                  'burst', '32kbit', 'latency', '50ms')  # fmt: skip

    def destroy(self) -> list[str]:
        """Delete every namespace this object made (hosts first, the switch last: deleting a
        namespace deletes its veth ends, and with them their peers, and its bridge). Returns
        the names that could not be deleted (a process still inside keeps no name: none).
        """
        failed = []
        for ns in [n for n in self.made if n != self.switch] + [
            n for n in self.made if n == self.switch
        ]:
            proc = subprocess.run(['ip', 'netns', 'del', ns], capture_output=True, text=True)
            if proc.returncode != 0 and ns in list_namespaces(ns):
                failed.append(ns)
        self.made = [n for n in self.made if n in failed]
        return failed

    def leftovers(self) -> list[str]:
        """Namespaces of this run that still exist (empty after a successful destroy)."""
        return [ns for ns in list_namespaces() if ns.endswith(f'_{self.suffix}')]

    # ------------------------------------------------------------------ at run time
    def set_link(self, rid: int, up: bool) -> None:
        """Robot ``rid``'s cable at the switch: its switch port down (the robot's eth0 loses its
        carrier, nothing gets through in either direction) or up again.
        """
        self._ip(self.switch, 'link', 'set', self.ports[rid], 'up' if up else 'down')

    def counters(self) -> dict:
        """{host: (bytes the host sent, bytes sent to the host)} from the switch ports' counters
        (port rx = from the host, port tx = to the host).
        """
        links = json.loads(self._ip(self.switch, '-s', '-j', 'link', 'show'))
        by_port = {}
        for link in links:
            stats = link.get('stats64') or link.get('stats') or {}
            by_port[link.get('ifname')] = (
                int(stats.get('rx', {}).get('bytes', 0)),
                int(stats.get('tx', {}).get('bytes', 0)),
            )
        return {host: by_port.get(port, (0, 0)) for host, port in self.ports.items()}
