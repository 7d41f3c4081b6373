"""What one robot's computer spends on its robot (issue "Robots as separate hosts"):
run with `bench/run.sh bench_robot_process.py [options]`.

1. Cost per robot at 100 Hz, two layouts in the same run on the simulated twin
   (scripts/launch_sim.sh: world, tracker, coordinator as usual):
     split  a formation_bridge and a formation_controller process per robot (today's default of
            launch_sim.sh; what launch_robot.sh --split starts);
     robot  one robot process per robot: formation_team hosting that robot's bridge and controller
            (launch_sim.sh --team 1; what launch_robot.sh starts by default).
   For each, idle and (``--quota``) with every robot's processes in a cgroup of their own with a
   CPU quota (default 25 % of one core: cgroup v2 cpu.max "25000 100000", or cgroup v1
   cpu.cfs_quota_us / cpu.rt_runtime_us 25000 per 100000 us; the groups are removed afterwards).
   Measured over a fixed window once every controller runs the mission:
     CPU %    utime + stime of the robot's processes from /proc/<pid>/stat, per 100 % of one core
     RSS      VmRSS of the robot's processes from /proc/<pid>/status (summed)
     late     late control ticks / ticks from the controllers' /diagnostics (a tick more than
              1.5 periods after the previous one)
2. (``--paper``) The paper scenario (config/scenarios/paper.yaml, 55 s) through `formation run`
   with one robot process per robot, idle, next to two CPU-bound processes (``hogs``) and with each
   robot process under the quota: prohibited entries, settled formation RMS and avoidance entries
   per robot, and the controlled stops (``stopped_pose``) and outlier-rejected camera poses the
   controllers logged.

Options: --window-s S (default 15), --layouts split robot, --no-idle, --quota [PCT], --paper
[idle hogs quota], --rt-priority P (control loops under SCHED_FIFO P: launch_sim.sh
--control-rt), --control-nice N. The machine's other load is printed (load average): figures
from a shared machine are only comparable within one run.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ament_formation.tools.run_cmd import loopback_env  # noqa: E402

SCENARIO = ROOT / "config" / "scenarios" / "paper.yaml"
HZ = os.sysconf("SC_CLK_TCK")


# ------------------------------------------------------------------ /proc
def cpu_ticks(pid: int) -> int:
    """utime + stime of ``pid`` (all its threads) [clock ticks]; 0 once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[11]) + int(fields[12])


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def read_pids(path: Path) -> dict[str, int]:
    """NAME -> PID from a launcher's pids file ("PID NAME" per line)."""
    if not path.exists():
        return {}
    out = {}
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) == 2:
            out[parts[1]] = int(parts[0])
    return out


# ------------------------------------------------------------------ cgroups
class CpuQuota:
    """A child cgroup with a CPU quota of ``pct`` % of one core (v2 cpu.max, else v1 cpu
    controller: CFS quota and, when the kernel groups real-time tasks, the same real-time runtime,
    so SCHED_FIFO threads are held to it too). :meth:`add` moves a process (all its threads) in;
    :meth:`remove` moves what is left back to the parent and deletes the group."""

    PERIOD_US = 100_000

    def __init__(self, name: str, pct: float):
        quota = int(self.PERIOD_US * pct / 100.0)
        v2 = Path("/sys/fs/cgroup/cgroup.controllers")
        if v2.exists() and "cpu" in v2.read_text().split():
            self.parent = Path("/sys/fs/cgroup")
            sub = self.parent / "cgroup.subtree_control"
            if "cpu" not in sub.read_text().split():
                sub.write_text("+cpu")
            self.path = self.parent / name
            self.path.mkdir(exist_ok=True)
            (self.path / "cpu.max").write_text(f"{quota} {self.PERIOD_US}")
        elif Path("/sys/fs/cgroup/cpu/cpu.cfs_quota_us").exists():
            self.parent = Path("/sys/fs/cgroup/cpu")
            self.path = self.parent / name
            self.path.mkdir(exist_ok=True)
            (self.path / "cpu.cfs_period_us").write_text(str(self.PERIOD_US))
            (self.path / "cpu.cfs_quota_us").write_text(str(quota))
            if (self.path / "cpu.rt_runtime_us").exists():
                (self.path / "cpu.rt_period_us").write_text(str(self.PERIOD_US))
                (self.path / "cpu.rt_runtime_us").write_text(str(quota))
        else:
            raise SystemExit("no cgroup cpu controller found under /sys/fs/cgroup")

    def add(self, pid: int) -> None:
        (self.path / "cgroup.procs").write_text(str(pid))

    def throttled(self) -> tuple[int, float]:
        """(periods throttled, seconds throttled) so far."""
        stat = {}
        try:
            for line in (self.path / "cpu.stat").read_text().splitlines():
                k, v = line.split()
                stat[k] = int(v)
        except OSError:
            return 0, 0.0
        if "throttled_usec" in stat:
            return stat.get("nr_throttled", 0), stat["throttled_usec"] * 1e-6
        return stat.get("nr_throttled", 0), stat.get("throttled_time", 0) * 1e-9

    def remove(self) -> None:
        try:
            for pid in (self.path / "cgroup.procs").read_text().split():
                try:
                    (self.parent / "cgroup.procs").write_text(pid)
                except OSError:
                    pass
            self.path.rmdir()
        except OSError:
            pass


# ------------------------------------------------------------------ diagnostics probe
class DiagProbe:
    """Latest controller diagnostics values per robot (ticks, late_ticks, safety)."""

    def __init__(self):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from ament_formation.ros.qos import QOS_DIAGNOSTICS

        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node("_bench_robot_probe", context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.values: dict[str, dict] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, QOS_DIAGNOSTICS)

    def _on(self, msg) -> None:
        for st in msg.status:
            if not st.name.startswith("formation_controller"):
                continue
            vals = {kv.key: kv.value for kv in st.values}
            if "late_ticks" in vals and "safety" in vals:
                robot = (st.hardware_id or st.name.split()[-1]).strip()
                self.values[robot] = {**vals, "_message": st.message}

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.05)

    def spin_until(self, pred, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if pred():
                return True
            self.ex.spin_once(timeout_sec=0.05)
        return pred()

    COUNTERS = ("ticks", "late_ticks", "camera_accepted", "rejected_outlier", "rejected_stale")

    def ticks(self) -> dict[str, tuple[int, ...]]:
        """Per robot: the :data:`COUNTERS` (ticks, late ticks, camera poses accepted / rejected)."""
        return {k: tuple(int(v.get(c, 0)) for c in self.COUNTERS) for k, v in self.values.items()}

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


# ------------------------------------------------------------------ part 1
def robot_processes(layout: str, pids: dict[str, int], ids: list[int]) -> dict[int, list[int]]:
    if layout == "split":
        return {i: [pids[f"bridge_{i}"], pids[f"controller_{i}"]] for i in ids
                if f"bridge_{i}" in pids and f"controller_{i}" in pids}
    return {i: [pids[f"team_{k}"]] for k, i in enumerate(ids) if f"team_{k}" in pids}


def measure_cost(layout: str, quota_pct: float | None, window_s: float, tmp: Path, probe: DiagProbe,
                 extra: list[str], scenario: Path = SCENARIO) -> dict:
    from ament_formation.core.scenario import load_scenario

    ids = list(load_scenario(scenario).robot_ids)
    run_dir = tmp / f"cost_{layout}_{'quota' if quota_pct else 'idle'}"
    cmd = [str(ROOT / "scripts" / "launch_sim.sh"), str(scenario), "--run-dir", str(run_dir),
           "--duration", "400", *(["--team", "1"] if layout == "robot" else []), *extra]
    launch = subprocess.Popen(cmd, stdout=open(tmp / f"{run_dir.name}.out", "w"), stderr=subprocess.STDOUT,
                              start_new_session=True)
    groups: list[CpuQuota] = []
    probe.values.clear()
    try:
        procs: dict[int, list[int]] = {}
        probe.spin_until(lambda: len(robot_processes(layout, read_pids(run_dir / "pids"), ids)) == len(ids)
                         or launch.poll() is not None, 120.0)
        procs = robot_processes(layout, read_pids(run_dir / "pids"), ids)
        if quota_pct:
            for i, plist in procs.items():
                g = CpuQuota(f"af_bench_{os.getpid()}_robot_{i}", quota_pct)
                groups.append(g)
                for pid in plist:
                    g.add(pid)
        running = probe.spin_until(lambda: len(probe.values) == len(ids) and all(
            v["_message"] == "running" for v in probe.values.values()) or launch.poll() is not None, 240.0)
        if not running:
            return {"layout": layout, "error": f"not every controller ran the mission: {probe.values and {k: v['_message'] for k, v in probe.values.items()}}"}
        probe.spin_for(2.0)
        t0, c0, d0 = time.monotonic(), {i: sum(cpu_ticks(p) for p in pl) for i, pl in procs.items()}, probe.ticks()
        thr0 = [g.throttled() for g in groups]
        probe.spin_for(window_s)
        probe.spin_for(1.2)      # the diagnostics of the window's end (published every second)
        t1, c1, d1 = time.monotonic(), {i: sum(cpu_ticks(p) for p in pl) for i, pl in procs.items()}, probe.ticks()
        dt = t1 - t0
        rows = {}
        for i, pl in procs.items():
            key = next((k for k in d1 if k.endswith(f"robot_{i}")), None)
            delta = [0] * len(probe.COUNTERS)
            if key is not None and key in d0:
                delta = [b - a for a, b in zip(d0[key], d1[key])]
            rows[i] = {"cpu_pct": 100.0 * (c1[i] - c0[i]) / HZ / dt, "rss_mb": sum(rss_mb(p) for p in pl),
                       "ticks": delta[0], "late": delta[1], "camera": delta[2:], "processes": len(pl)}
        thr = [(b[0] - a[0], b[1] - a[1]) for a, b in zip(thr0, (g.throttled() for g in groups))]
        return {"layout": layout, "quota_pct": quota_pct, "window_s": dt, "robots": rows, "throttled": thr}
    finally:
        if launch.poll() is None:
            launch.send_signal(signal.SIGTERM)
            try:
                launch.wait(timeout=30)
            except subprocess.TimeoutExpired:
                launch.kill()
                launch.wait()
        for g in groups:
            g.remove()


# ------------------------------------------------------------------ part 2
def hog() -> subprocess.Popen:
    """A CPU-bound process (a busy loop) beside the system."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def paper_run(condition: str, quota_pct: float, tmp: Path, extra: list[str]) -> dict:
    out = tmp / f"paper_{condition}"
    cmd = [str(ROOT / ".venv" / "bin" / "formation"), "run", str(SCENARIO), "--out", str(out), "--team", "1",
           "--no-figure", "--quiet", *extra]
    hogs = [hog(), hog()] if condition == "hogs" else []
    groups: list[CpuQuota] = []
    t0 = time.monotonic()
    run = subprocess.Popen(cmd, stdout=open(tmp / f"paper_{condition}.out", "w"), stderr=subprocess.STDOUT,
                           start_new_session=True)
    try:
        moved: set[int] = set()
        while run.poll() is None:
            if condition == "quota":
                for name, pid in read_pids(out / "processes" / "pids").items():
                    if name.startswith("team_") and pid not in moved:
                        g = CpuQuota(f"af_bench_{os.getpid()}_{name}", quota_pct)
                        groups.append(g)
                        g.add(pid)
                        moved.add(pid)
            time.sleep(0.2)
        rc = run.returncode
    finally:
        for h in hogs:
            h.kill()
            h.wait()
        if run.poll() is None:
            run.send_signal(signal.SIGTERM)
            run.wait(timeout=60)
        for g in groups:
            g.remove()
    res = {"condition": condition, "rc": rc, "wall_s": time.monotonic() - t0}
    mpath = out / "metrics.json"
    if mpath.exists():
        m = json.loads(mpath.read_text())
        res["prohibited_entries"] = m["prohibited_entries"]
        res["robots"] = {rid: {"rms_mm": 1e3 * r["formation_rms_settled_m"], "entries": r["avoidance_entries"]}
                         for rid, r in m["robots"].items()}
    logs = "".join(p.read_text(errors="replace") for p in (out / "processes").glob("team_*.log"))
    res["stopped_pose"] = logs.count("-> stopped_pose")
    res["hold_parent"] = logs.count("-> hold_parent")
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--window-s", type=float, default=15.0)
    ap.add_argument("--layouts", nargs="+", choices=("split", "robot"), default=["split", "robot"])
    ap.add_argument("--no-idle", action="store_true", help="skip the runs without a quota")
    ap.add_argument("--quota", type=float, nargs="?", const=25.0, default=None, metavar="PCT",
                    help="also run with every robot's processes under a CPU quota of PCT %% of a core (default 25)")
    ap.add_argument("--paper", nargs="*", choices=("idle", "hogs", "quota"), default=None,
                    help="paper scenario through `formation run --team 1` under these conditions")
    ap.add_argument("--rt-priority", type=int, default=None, metavar="P",
                    help="control loops under SCHED_FIFO priority P (launch_sim.sh --control-rt)")
    ap.add_argument("--control-nice", type=int, default=None, metavar="N")
    ap.add_argument("--keep", action="store_true", help="keep the run folders")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="ament_formation_bench_robot_"))
    loopback_env(tmp / "ros_log")
    extra = ([] if args.rt_priority is None else ["--control-rt", str(args.rt_priority)]) + \
            ([] if args.control_nice is None else ["--control-nice", str(args.control_nice)])
    if args.rt_priority is not None:
        os.environ["AF_CONTROL_RT_PRIORITY"] = str(args.rt_priority)   # formation run -> launch_sim.sh
    print(f"load average before: {os.getloadavg()}; {os.cpu_count()} cores; options: {' '.join(extra) or 'none'}")
    try:
        conditions = ([] if args.no_idle else [None]) + ([args.quota] if args.quota else [])
        if conditions:
            probe = DiagProbe()
            try:
                print(f"{'layout':7} {'quota':>6} {'robot':>5} {'CPU %':>7} {'RSS MB':>7} {'ticks':>6} {'late':>5} "
                      f"{'late %':>7}  camera poses accepted/outlier/stale")
                for q in conditions:
                    for layout in args.layouts:
                        r = measure_cost(layout, q, args.window_s, tmp, probe, extra)
                        if "error" in r:
                            print(f"{layout:7} {q or '-':>6} {r['error']}")
                            continue
                        for i, row in r["robots"].items():
                            pct = 100.0 * row["late"] / row["ticks"] if row["ticks"] else float("nan")
                            print(f"{layout:7} {q or '-':>6} {i:5d} {row['cpu_pct']:7.1f} {row['rss_mb']:7.0f} "
                                  f"{row['ticks']:6d} {row['late']:5d} {pct:7.2f}  {'/'.join(map(str, row['camera']))}")
                        if r["throttled"]:
                            print(f"        cgroup throttling in the window: {r['throttled']}")
                        print(f"        (window {r['window_s']:.1f} s, load average {os.getloadavg()[0]:.1f})")
            finally:
                probe.close()
        for cond in args.paper or ():
            r = paper_run(cond, args.quota or 25.0, tmp, extra)
            robots = r.get("robots", {})
            print(f"paper {cond:6}: prohibited entries {r.get('prohibited_entries')}, settled RMS "
                  + ", ".join(f"R{k} {v['rms_mm']:.1f} mm" for k, v in robots.items()) + ", avoidance entries "
                  + ", ".join(f"R{k} {v['entries']}" for k, v in robots.items())
                  + f"; stopped_pose {r['stopped_pose']}, hold_parent {r['hold_parent']} (rc {r['rc']}, "
                  f"{r['wall_s']:.0f} s wall, load {os.getloadavg()[0]:.1f})")
    finally:
        if args.keep:
            print(f"run folders kept in {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
