"""A robot as a tree of hinge-jointed links: what the builder turns into an MJCF model.

A description holds only design intent (joint axes, link geometry, masses, how many IMUs per link).
The ground truth of a built robot is always read back from the compiled MuJoCo model
(:func:`simulators.robot.truth_from_model`), never from this tree, so a bug here cannot hide behind
matching bookkeeping.

Example
-------
>>> arm = RobotDescription(
...     name="two-link",
...     links=(LinkSpec("upper", "j1", axis=(0, 0, 1), end=(0.2, 0, 0), children=(
...         LinkSpec("fore", "j2", axis=(0, 1, 0), pos=(0.2, 0, 0), end=(0.2, 0, 0)),)),),
...     imus_per_link=3)
>>> [link.joint for link in arm.iter_links()], arm.n_imus
(['j1', 'j2'], 6)
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

__all__ = ["LinkSpec", "RobotDescription"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class LinkSpec:
    """One link and the hinge joint that carries it.

    ``pos``/``quat`` (wxyz) place the link frame (and the joint, at its origin) in the parent link's
    frame. The link's body is a capsule from the origin to ``end`` (link frame) of ``radius``; a zero
    ``end`` makes it a sphere. ``imus`` overrides the robot's ``imus_per_link`` for this link.
    """

    name: str
    joint: str
    axis: Vec3 = (0.0, 0.0, 1.0)
    pos: Vec3 = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    end: Vec3 = (0.0, 0.0, 0.2)
    radius: float = 0.03
    mass: float = 1.0
    range: tuple[float, float] | None = None
    imus: int | None = None
    children: tuple[LinkSpec, ...] = ()


@dataclass(frozen=True)
class RobotDescription:
    """A fixed-base robot: a base box and a forest of links mounted on it.

    ``seed`` fixes the arbitrary in-plane (x/y) orientation of each IMU about its surface normal, so a
    catalog robot is the same model every time it is built.
    """

    name: str
    links: tuple[LinkSpec, ...]
    imus_per_link: int = 12
    base_imus: int = 0
    base_half_size: Vec3 = (0.08, 0.08, 0.04)
    base_mass: float = 5.0
    damping: float = 0.05
    armature: float = 0.01
    seed: int = 0
    summary: str = ""

    def iter_links(self) -> Iterator[LinkSpec]:
        """Links depth-first, parents before children (the order joints get in the model)."""
        stack = list(reversed(self.links))
        while stack:
            link = stack.pop()
            yield link
            stack.extend(reversed(link.children))

    @property
    def n_joints(self) -> int:
        return sum(1 for _ in self.iter_links())

    @property
    def n_imus(self) -> int:
        per = [self.imus_per_link if lk.imus is None else lk.imus for lk in self.iter_links()]
        return self.base_imus + sum(per)
