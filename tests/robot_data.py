"""Where the measured robot logs and their import maps are: ``$BODYHEALTH_ROBOTS_DIR`` when set, else
the team's shared folder beside the checkout (``<repo>/../shared/data/robots``)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["MAPS", "REPO_ROOT", "ROBOTS"]

REPO_ROOT = Path(__file__).resolve().parents[1]
ROBOTS = Path(os.environ.get("BODYHEALTH_ROBOTS_DIR") or REPO_ROOT.parent / "shared" / "data" / "robots")
#: The import maps shipped for those logs.
MAPS = REPO_ROOT / "examples" / "import"
