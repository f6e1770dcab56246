"""Writing matplotlib figures: every PNG the service, its commands and its benchmarks draw goes through
:func:`save_figure`, so layout, folder creation and closing (figures otherwise stay in pyplot's
registry for the life of the process) happen one way."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = ["save_figure"]


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 80) -> Path:
    """Lay ``fig`` out, write it as PNG to ``path`` (creating the folder), close it; returns the path.

    >>> import matplotlib; matplotlib.use("Agg")
    >>> import matplotlib.pyplot as plt, tempfile
    >>> fig, ax = plt.subplots(); _ = ax.plot([0, 1])
    >>> out = save_figure(fig, Path(tempfile.mkdtemp()) / "sub" / "line.png")
    >>> out.stat().st_size > 1000, plt.fignum_exists(fig.number)
    (True, False)
    """
    import matplotlib.pyplot as plt

    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
