"""The store's database layer: models, engines/sessions and the migration runner."""

from service.db.engine import is_sqlite, make_engine, normalize_url, session_scope
from service.db.migrate import current_revision, downgrade, head_revision, known_revisions, upgrade
from service.db.models import (
    Alert,
    Base,
    Baseline,
    Chunk,
    Heartbeat,
    Imu,
    Joint,
    NetworkWeightsRow,
    Robot,
    TopologyRow,
)

__all__ = [
    "Alert",
    "Base",
    "Baseline",
    "Chunk",
    "Heartbeat",
    "Imu",
    "Joint",
    "NetworkWeightsRow",
    "Robot",
    "TopologyRow",
    "current_revision",
    "downgrade",
    "head_revision",
    "is_sqlite",
    "known_revisions",
    "make_engine",
    "normalize_url",
    "session_scope",
    "upgrade",
]
