"""One progress bar for the long loops of the package and the layers above it.

Training epochs and the discrepancy selection take seconds to minutes, so an interactive caller wants
a bar; a service or a test wants none. Every loop asks :func:`progress` for its bar and uses it the
same way whether it is shown or not: a disabled bar is a no-op with the same interface, so loops carry
no branches. A shown bar is ``tqdm`` writing to stderr, which keeps stdout free for results (a
command's JSON output, say); it is imported only when a bar is shown.

Example
-------
>>> bar = progress(total=3, desc="epochs", unit="epoch", enabled=False)
>>> for _ in range(3):
...     bar.update(1)
...     bar.set_postfix(loss="0.1")
>>> bar.close()
>>> list(progress(range(3), desc="items", unit="item", enabled=False))
[0, 1, 2]
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import Any, Protocol

__all__ = ["ProgressBar", "progress"]


class ProgressBar(Protocol):
    """What a loop may do with its bar: the subset of ``tqdm``'s interface used here."""

    def __iter__(self) -> Iterator[Any]: ...

    def update(self, n: float = 1) -> bool | None: ...

    def set_postfix(self, ordered_dict: Any = None, refresh: bool = True, **kwargs: Any) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> ProgressBar: ...

    def __exit__(self, *exc: object) -> None: ...


class _NoBar:
    """A bar that shows nothing: iterates its iterable unchanged and ignores every update."""

    def __init__(self, iterable: Iterable[Any] | None) -> None:
        self._iterable = iterable

    def __iter__(self) -> Iterator[Any]:
        return iter(self._iterable if self._iterable is not None else ())

    def update(self, n: float = 1) -> bool | None:
        return None

    def set_postfix(self, ordered_dict: Any = None, refresh: bool = True, **kwargs: Any) -> None:
        return None

    def close(self) -> None:
        return None

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress(
    iterable: Iterable[Any] | None = None,
    *,
    total: int | None = None,
    desc: str,
    unit: str,
    enabled: bool = True,
    leave: bool = False,
) -> ProgressBar:
    """A progress bar over ``iterable`` (or updated by hand up to ``total``), shown when ``enabled``.

    ``desc`` names the loop and ``unit`` what one step is; ``leave`` keeps the finished bar on the
    screen. Shown, it is a ``tqdm`` bar on stderr; otherwise a no-op bar with the same interface.
    """
    if not enabled:
        return _NoBar(iterable)
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, file=sys.stderr)
