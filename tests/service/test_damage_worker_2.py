"""The damage suite (tests/service/damage_runs.py), share 2 of 3 of the catalog's robots: every
damage kind on each robot, through the worker's real cycle, alerts first with its kind on its part,
and the nominal run raises nothing."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.service.damage_runs import check, quiet_alert_log, robot_seed, run_robot, share

__all__ = ["quiet_alert_log"]

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("catalog_name", share(1))
def test_every_damage_alerts_first_with_its_kind_on_robot_sensing(catalog_name: str, tmp_path: Path) -> None:
    check(run_robot(catalog_name, robot_seed(catalog_name), tmp_path))
