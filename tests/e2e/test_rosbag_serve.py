"""``bodyhealth serve --source rosbag:...`` as a process: a ROS 2 bag written from a simulated robot on the
realistic ``robot`` preset is replayed into the service, and the robot's frames arrive (its joints, IMUs
and the bag's last stamp) as GET /api/v1/robots reports them."""

from __future__ import annotations

import os
import time
from pathlib import Path

import httpx
import pytest

from emulators.rosbag import RosbagWriteOptions, write_rosbag
from service.ingest.rosbag import read_rosbag
from simulators.simulation import simulate
from tests.e2e.processes import start_service

pytestmark = [pytest.mark.e2e]

ROOT = Path(__file__).resolve().parents[2]


def test_serve_replays_a_rosbag(e2e_db_url: str, tmp_path: Path) -> None:
    rec = simulate("ur5e", seconds=4.0, seed=11, sensing="robot")
    bag = tmp_path / "cell_7"
    write_rosbag(rec, bag, RosbagWriteOptions(format="mcap"))
    imported, _ = read_rosbag(bag)
    last_t = max(float(imported.t[-1]), float(imported.encoder_t[-1]))
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("BODYHEALTH_")},
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
    }
    proc, url = start_service(
        e2e_db_url, "--source", f"rosbag:{bag}@max", err=tmp_path / "serve.err", env=env, cwd=tmp_path
    )
    try:
        with httpx.Client(base_url=url, timeout=30) as c:
            deadline = time.monotonic() + 90
            robots: list[dict] = []
            while True:
                assert proc.poll() is None, (tmp_path / "serve.err").read_text()[-3000:]
                try:
                    robots = c.get("/api/v1/robots").json()
                except httpx.HTTPError:
                    robots = []
                if robots and robots[0]["last_frame_t"] == pytest.approx(last_t, abs=1e-6):
                    break
                assert time.monotonic() < deadline, f"frames did not arrive within 90 s: {robots}"
                time.sleep(0.2)
        (robot,) = robots
        assert robot["name"] == "cell_7"  # named after the bag
        assert robot["joints"] == list(rec.joint_names)
        assert robot["imus"] == list(rec.imu_names)
        assert robot["simulated"] is False and robot["silent_imus"] == []
    finally:
        proc.terminate()
        proc.wait(15)
