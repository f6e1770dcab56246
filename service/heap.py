"""The served process's long-lived objects, taken out of Python's cyclic garbage collector.

By the time the service listens, its interpreter holds some 340,000 objects that live as long as the
process: the modules, classes and functions of FastAPI, SQLAlchemy, pydantic, numpy, scipy, Dask and
torch. CPython's oldest generation is collected whenever enough objects have survived the younger ones
(a quarter of what it holds), and a collection walks every tracked object while holding the
interpreter lock: 240 ms for those 340,000 on a 2-core machine, during which no request is answered.
Under the ingest of a fleet that happened every 10 to 20 seconds, and it was the API's latency tail
(docs/bench/fleet.md). :func:`gc.freeze` moves every object alive now to a permanent generation that
no collection visits (Python's documented use: after start-up, before serving), so the collections
that follow walk only what was made since. Frozen objects are never freed by the collector; they are
the process's own code and stay alive anyway.

>>> import gc
>>> frozen = freeze_startup_heap()
>>> frozen > 1000 and gc.get_freeze_count() > 1000
True
>>> gc.unfreeze()  # a test process goes on collecting as before
"""

from __future__ import annotations

import gc

__all__ = ["freeze_startup_heap"]


def freeze_startup_heap() -> int:
    """Collect what start-up left as garbage, then freeze every object alive (module doc); returns
    how many objects the permanent generation holds then (fewer later: an object freed by its
    reference count leaves it)."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
