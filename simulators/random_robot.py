"""Random MuJoCo robots: random trees, random joint axes, IMUs at random surface poses.

The catalog's robots were drawn by hand (axes along x, y or z, links of a few fixed lengths), and an
estimator tuned on them can lean on that regularity. A robot drawn here has a random out-tree
(:func:`simulators.kinematic_tree.random_tree`), each joint axis a random unit vector, each link a
random length and direction, and one or two IMUs at random points of its surface with a random spin
about the normal (:func:`simulators.builder.add_imus` does the placing). Masses shrink with depth so
that deep trees still move under the servo excitation. Everything is drawn from the ``rng`` passed in.

Example
-------
>>> import numpy as np
>>> desc = random_description(np.random.default_rng(0), 5)
>>> desc.n_joints, 5 <= desc.n_imus <= 11
(5, True)
>>> robot = random_robot(np.random.default_rng(0), 5, rate=200.0)
>>> len(robot.joint_names), robot.n_imus == desc.n_imus
(5, True)
"""

from __future__ import annotations

import numpy as np

from simulators.builder import build_spec
from simulators.description import LinkSpec, RobotDescription
from simulators.kinematic_tree import random_tree
from simulators.robot import Robot

__all__ = ["random_description", "random_robot"]


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def random_description(
    rng: np.random.Generator, n_joints: int, imus_per_link: tuple[int, int] = (1, 2), name: str = ""
) -> RobotDescription:
    """A random robot of ``n_joints`` hinges (see the module docstring); one IMU on the base."""
    if n_joints < 1:
        raise ValueError("n_joints must be >= 1")
    parent = random_tree(rng, n_joints)
    depth = [0] * n_joints
    for j, p in enumerate(parent):
        depth[j] = 0 if p < 0 else depth[p] + 1
    length = rng.uniform(0.12, 0.3, size=n_joints)
    direction = [_unit(rng) for _ in range(n_joints)]
    axis = [_unit(rng) for _ in range(n_joints)]
    imus = rng.integers(imus_per_link[0], imus_per_link[1] + 1, size=n_joints)
    seed = int(rng.integers(2**31))

    def link(j: int) -> LinkSpec:
        kids = tuple(link(c) for c in range(n_joints) if parent[c] == j)
        # a child joint sits at the parent link's far end, or part-way along it
        if parent[j] < 0:
            pos = tuple(float(x) for x in rng.uniform(-0.06, 0.06, size=3) * (1, 1, 0) + (0, 0, 0.04))
        else:
            frac = rng.uniform(0.5, 1.0)
            pos = tuple(float(x) for x in frac * length[parent[j]] * direction[parent[j]])
        return LinkSpec(
            name=f"link{j + 1}",
            joint=f"j{j + 1}",
            axis=tuple(float(x) for x in axis[j]),  # type: ignore[arg-type]
            pos=pos,  # type: ignore[arg-type]
            end=tuple(float(x) for x in length[j] * direction[j]),  # type: ignore[arg-type]
            radius=0.025,
            mass=float(0.8 * 0.75 ** depth[j]),
            imus=int(imus[j]),
            children=kids,
        )

    roots = tuple(link(j) for j in range(n_joints) if parent[j] < 0)
    return RobotDescription(
        name=name or f"random-{n_joints}",
        links=roots,
        imus_per_link=1,
        base_imus=1,
        seed=seed,
        summary=f"{n_joints} joints, random tree, axes and IMU poses",
    )


def random_robot(
    rng: np.random.Generator, n_joints: int, *, rate: float = 100.0, imus_per_link: tuple[int, int] = (1, 2)
) -> Robot:
    """:func:`random_description` built and compiled as a :class:`simulators.robot.Robot`."""
    desc = random_description(rng, n_joints, imus_per_link)
    return Robot(build_spec(desc), name=desc.name, rate=rate)
