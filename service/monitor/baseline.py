"""A robot without a baseline gets one (the worker's step 4): the fast topology once it has come out
the same ``baseline_repeat_k`` cycles in a row from healthy signals. With the sensor networks on they
are the authority: the baseline adopted is their newest topology, once it has the structure of the
fast streak; until one does, the streak waits and a network retrain is asked for, and after
``baseline_unconfirmed_cycles`` cycles and ``baseline_unconfirmed_seconds`` of wall time without their
answer the fast body is adopted, marked so.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from bodyschema.diff import is_ambiguous
from bodyschema.health import SignalHealth
from bodyschema.topology import Topology
from bodyschema.verdict import contradicts
from service.monitor.confirmation import NetworkAsks
from service.monitor.state import RobotState
from service.settings import Settings
from service.store import Store, TopologyRecord

__all__ = ["BaselineAdoption"]

log = logging.getLogger("service.worker")


class BaselineAdoption:
    """Adopts a robot's baseline from its streak of fast topologies (module doc)."""

    def __init__(
        self, store: Store, settings: Settings, clock: Callable[[], float], asks: NetworkAsks
    ) -> None:
        self.store = store
        self.settings = settings
        self.clock = clock
        self.asks = asks

    def offer(
        self, robot: str, state: RobotState, topo: Topology, health: SignalHealth, window_end: float
    ) -> bool:
        """Adopt ``topo`` once K consecutive cycles learned the same structure from healthy signals;
        True when a baseline was adopted."""
        k = self.settings.baseline_repeat_k
        streak = state.streak
        # Only a trustworthy body becomes the reference: every IMU alive, one tree that fits (unique),
        # every joint placed and moving in this window (a still joint cannot be told from a locked
        # one later).
        still = [j for j, h in health.joints.items() if not (h.encoder_moving or h.link_moving)]
        if is_ambiguous(topo):
            return False  # no information either way: the streak neither grows nor breaks
        if health.dead_imus or topo.undetermined or still or not topo.joint_parent:
            streak.clear()
            return False
        last = streak.topologies[-1] if streak.topologies else None
        if last is not None and not (last.same_structure(topo) and last.undetermined == topo.undetermined):
            streak.clear()
        streak.add(topo, window_end, k)
        if len(streak.topologies) < k:
            return False
        net, source = None, "auto"
        if self.asks.networks_on:
            net = self.store.latest_topology(robot, method="network")
            if net is None or is_ambiguous(net.topology) or not net.topology.same_structure(topo):
                # the networks are the authority: the streak waits (it stays complete) for a network
                # topology of the same body; asked for once per streak, then the schedule's retrains
                if streak.since is None:
                    streak.since = window_end
                if streak.wall is None:
                    streak.wall = self.clock()
                self.asks.ask(
                    robot, state, net, streak.since, "a baseline needs the sensor networks' agreement"
                )
                if not self.networks_late(state, net, self.clock()):
                    return False
                # ... unless they are late: the fast body that held this long is adopted, marked so
                net, source = None, "fast-unconfirmed"
            else:
                topo = net.topology
        self._adopt(robot, state, topo, net, source, window_end)
        return True

    def _adopt(
        self,
        robot: str,
        state: RobotState,
        topo: Topology,
        net: TopologyRecord | None,
        source: str,
        window_end: float,
    ) -> None:
        """Store ``topo`` as the baseline (from ``source``, with the weights of ``net`` when the
        networks made it) and forget what its adoption forgets."""
        base_id = self.store.set_baseline(
            robot, topo, source, wall_time=self.clock(), window_end_t=window_end
        )
        if net is not None:  # the weights that learned this baseline are its weights
            self.store.adopt_network_weights(
                robot, "network", window_end_t=net.window_end_t, baseline_id=base_id
            )
        n = state.streak.n
        state.reset("adopted")  # the fingerprints come from the next window that matches it
        state.baseline_id, state.baseline_known = base_id, True  # the worker's own: nothing to forget
        log.log(
            logging.INFO if source == "auto" else logging.WARNING,
            "baseline learned"
            if source == "auto"
            else "baseline adopted unconfirmed: the sensor networks are late",
            extra={"robot": robot, "source": source, "repeats": n},
        )

    def networks_late(self, state: RobotState, net: TopologyRecord | None, now: float) -> bool:
        """True when the fast screen's body held ``baseline_unconfirmed_cycles`` cycles, its complete
        streak waited ``baseline_unconfirmed_seconds`` (wall), and the sensor networks have not answered
        on a window that ended after it first held (a network answer from after it that disagrees is
        not late: it is the authority's word, and the streak waits; so is an ambiguous one that decides
        a part against the streak's body: every tree it lists says otherwise)."""
        need = self.settings.baseline_unconfirmed_cycles
        if not need or state.streak.n < need:
            return False
        waited = 0.0 if state.streak.wall is None else now - state.streak.wall
        if waited < self.settings.baseline_unconfirmed_seconds:
            return False
        start = np.inf if state.streak.start is None else state.streak.start
        if net is None or net.window_end_t is None or net.window_end_t < start:
            return True
        if not is_ambiguous(net.topology):
            return False  # a unique answer from after the streak began: the authority's word
        return not contradicts(net.topology, state.streak.topologies[-1])

    def waiting(self, state: RobotState) -> tuple[str, float] | None:
        """What a robot whose streak waits for the networks waits on, and since when (wall time)."""
        if state.streak.wall is None:
            return None
        n, need = state.streak.n, self.settings.baseline_unconfirmed_cycles
        secs = self.settings.baseline_unconfirmed_seconds
        later = f", adopted unconfirmed after {need} cycles and {secs:g} s" if need else ""
        return (
            f"baseline: the sensor networks' answer (the fast screen's body held {n} cycles{later})",
            state.streak.wall,
        )
