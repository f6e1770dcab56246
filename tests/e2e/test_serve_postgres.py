"""``bodyhealth serve --demo`` at 20× real time on a PostgreSQL database made for the test: every
robot's true body learned, an IMU's and a joint's damage each raise their alert on their part, the
healthy robots raise nothing, SIGTERM stops it (tests/e2e/demo.py). The SQLite run
(tests/e2e/test_serve.py) injects the other four kinds, so each kind passes the whole process once;
every kind on every robot through the worker's real cycle is the damage suite's
(tests/service/test_damage_worker*.py); the store's PostgreSQL paths are the service tests'. The
geometry's estimates are off here (both damages change the structure); the SQLite run has them on.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.e2e.demo import DAMAGES, PG_KINDS, check_demo, demo_service

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

#: An IMU detached and a link lost: an IMU's damage and a joint's.
PG_DAMAGES = [d for d in DAMAGES if d[0] in PG_KINDS]


@pytest.mark.parametrize(
    "e2e_db_url", [pytest.param("postgresql", marks=pytest.mark.postgres)], indirect=True
)
def test_demo_learns_baselines_and_alerts_on_each_damage(e2e_db_url: str, tmp_path: Path) -> None:
    assert [d[0] for d in PG_DAMAGES] == ["imu_detached", "link_lost"]
    with demo_service(e2e_db_url, tmp_path, geometry=False) as service:
        check_demo(service, PG_DAMAGES)
