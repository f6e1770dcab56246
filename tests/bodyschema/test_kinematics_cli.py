"""``bodyhealth kinematics`` and the URDF it writes: JSON values, and the URDF in yourdfpy and MuJoCo.

The URDF's forward kinematics must put each link's reference IMU where the simulator has it relative
to the reference IMU of the parent link: the rotation, and the offset except along a root parent's axis
(a fixed base shows no motion along it, docs/kinematics.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yourdfpy

from bodyschema.kinematics import Kinematics, estimate_kinematics
from bodyschema.topology import Topology
from bodyschema.urdf import to_urdf
from cli.main import main
from simulators.random_robot import random_robot
from simulators.recording_io import save_recording
from tests.builders import Case, record, truth_topology


@pytest.fixture(scope="module")
def case() -> Case:
    return record(random_robot(np.random.default_rng(3), 5, rate=1000.0), 20.0, seed=1, imu_model="ideal")


@pytest.fixture(scope="module")
def saved(case: Case, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("kin") / "rec.npz"
    save_recording(case.rec, path)
    return path


@pytest.mark.slow
def test_cli_json_urdf_and_plot(saved: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    urdf, png = tmp_path / "out.urdf", tmp_path / "out.png"
    assert main(["kinematics", str(saved), "--json", "--urdf", str(urdf), "--plot", str(png)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["imus"]["imu0"]["joint"] is None and out["imus"]["imu0"]["converged"] is False
    imu1 = out["imus"]["imu1"]
    assert imu1["joint"] == "j1" and imu1["converged"] is True
    assert abs(np.linalg.norm(imu1["axis"]) - 1.0) < 1e-5
    assert abs(float(np.dot(imu1["axis"], imu1["lever_arm"]))) < 1e-5
    assert set(out["joints"]) == {"j1", "j2", "j3", "j4", "j5"}
    assert out["joints"]["j2"]["parent"] == "j1" and out["joints"]["j2"]["axis_in_parent"]
    assert out["same_link"] and all(len(s["rotation"]) == 3 for s in out["same_link"])
    assert abs(out["band_hz"] - 10.0) < 0.1 and 10.0 < out["lag_ms"] < 16.0
    assert urdf.read_text().count('type="revolute"') == 5
    assert png.stat().st_size > 5000


def test_cli_given_topology_and_listing(saved: Path, case: Case, tmp_path: Path, capsys) -> None:
    topo = tmp_path / "t.json"
    topo.write_text(json.dumps(truth_topology(case.rec).to_json()))
    assert main(["kinematics", str(saved), "--topology", str(topo)]) == 0
    text = capsys.readouterr().out
    assert text.startswith("band 10.0 Hz, IMU lag ")
    assert "imu0  base  -- on the base" in text and text.count("  converged") == 7


def test_urdf_loads_and_matches_the_simulated_body(case: Case, tmp_path: Path) -> None:
    kin = estimate_kinematics(case.rec, truth_topology(case.rec))
    xml = to_urdf(kin, "learned")
    path = tmp_path / "learned.urdf"
    path.write_text(xml)
    robot = yourdfpy.URDF.load(str(path))
    assert sorted(robot.actuated_joint_names) == sorted(case.rec.joint_names)
    model = mujoco.MjModel.from_xml_string(xml)
    assert model.njnt == case.rec.n_joints
    assert "<!-- origin by convention" in xml and "placeholder inertia" in xml
    # what the service keeps (the JSON, 6 digits) gives the same body, the base joints' tilt included
    assert any(k.up_at_zero is not None for k in kin.imus.values())
    kept = tmp_path / "kept.urdf"
    kept.write_text(to_urdf(Kinematics.from_json(kin.to_json(), kin.topology), "learned"))
    again = yourdfpy.URDF.load(str(kept))
    for link in robot.link_map:
        assert np.allclose(again.get_transform(link), robot.get_transform(link), atol=1e-5), link

    # forward kinematics at the pose the simulation ended in
    sim_m, sim_d = case.robot.model, case.robot.data
    q = {j: float(sim_d.qpos[sim_m.jnt_qposadr[sim_m.joint(j).id]]) for j in case.rec.joint_names}
    robot.update_cfg(q)
    d = mujoco.MjData(sim_m)
    d.qpos[:] = sim_d.qpos
    mujoco.mj_kinematics(sim_m, d)
    checked = 0
    for jn, jk in kin.joints.items():
        parent = kin.joints.get(jk.parent) if jk.parent else None
        if parent is None or jk.ref_imu is None or parent.ref_imu is None:
            continue
        c, p = jk.ref_imu, parent.ref_imu
        T = robot.get_transform(frame_to=c, frame_from=p)
        Rp, Rc = (d.site_xmat[sim_m.site(n).id].reshape(3, 3) for n in (p, c))
        R_true = Rp.T @ Rc
        off_true = Rp.T @ (d.site_xpos[sim_m.site(c).id] - d.site_xpos[sim_m.site(p).id])
        angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3].T @ R_true) - 1) / 2, -1, 1)))
        assert angle < 0.5, (jn, angle)
        err = T[:3, 3] - off_true
        if kin.topology.joint_parent[jk.parent] is None:  # root parent: nothing along its axis
            u = kin.imus[p].axis
            err = err - u * float(u @ err)
        assert np.linalg.norm(err) < 5e-3, (jn, err)
        checked += 1
    assert checked >= 2


def test_urdf_of_a_never_moving_joint_still_loads(tmp_path: Path) -> None:
    case = record(
        random_robot(np.random.default_rng(3), 5, rate=1000.0), 6.0, seed=2, imu_model="ideal", lock="j2"
    )
    kin = estimate_kinematics(case.rec, Topology(case.rec.truth_parent_map, case.rec.truth_imu_map))
    xml = to_urdf(kin)
    assert "axis not observed" in xml
    assert mujoco.MjModel.from_xml_string(xml).njnt == 5
