"""`formation run`: the whole system as processes on the simulated twin, recorded to run.mcap,
evaluated from the recorded ground truth (a head-on encounter, 12.5 s of scenario)."""
import json
import subprocess
from pathlib import Path

from processes import alive

from ament_formation.ros import shm

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "test" / "data" / "head_on.yaml"


def test_formation_run_records_evaluates_and_stops_every_process(tmp_path):
    from ament_formation.ros.recorder import read_topic

    shm_before = shm.snapshot()
    out = tmp_path / "run"
    res = subprocess.run([str(ROOT / ".venv" / "bin" / "formation"), "run", str(SCENARIO), "--out", str(out),
                          "--quiet"], capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr[-2000:]

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "head_on"
    assert metrics["sim_time_s"] >= 12.0
    assert metrics["prohibited_entries"] == 0
    assert metrics["min_inter_robot_distance_m"] > 0.25          # keep-out circle R_aa (S7)
    assert {e["robot"] for e in metrics["mode_events"] if e["event"] == "enter"} == {0, 1}
    for rid in ("0", "1"):
        peak = metrics["robots"][rid]["peak_torque_nm"]
        assert 0.0 < max(peak) <= 0.15

    truth = read_topic(out / "run.mcap", "/world/truth/robot_0")
    torques = read_topic(out / "run.mcap", "/robot_1/wheel_torque")
    assert len(truth) > 100 and len(torques) > 100                # ~12 s of 100 Hz topics
    xs = [msg.pose.pose.position.x for _t, msg in truth]
    assert xs[-1] - xs[0] > 0.5                                    # robot 0 drove past the encounter
    assert (out / "figure.png").stat().st_size > 20_000
    assert (out / "trajectories.csv").exists()

    pids = [int(line.split()[0]) for line in (out / "processes" / "pids").read_text().splitlines()
            if line.strip()]                                       # "PID name" per process
    assert pids and not any(alive(p) for p in pids)
    # no Fast DDS segment of the run left in /dev/shm (lttng-ust-wait-* are shared by every
    # lttng-ust process of the user, this test process included, whose listener thread maps and
    # re-creates them on its own schedule: not the run's to answer for here)
    left = shm.snapshot() - shm_before - shm.mapped()
    assert {n for n in left if not n.startswith("lttng-ust-wait")} == set(), left


def test_formation_run_refuses_a_bad_scenario_in_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(SCENARIO.read_text().replace("duration_s: 12.5", "duration_s: -1"))
    res = subprocess.run([str(ROOT / ".venv" / "bin" / "formation"), "run", str(bad), "--out",
                          str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "duration_s" in lines[0] and "Traceback" not in res.stderr
