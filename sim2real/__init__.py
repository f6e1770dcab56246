"""Sim-to-real tooling, offline: the BROAD importer (:mod:`sim2real.broad`), the discrepancy report
and simulator transfer (:mod:`sim2real.report`) and the one PNG writer every offline tool uses
(:mod:`sim2real.figures`).

None of it runs inside the service; it reads measured data and writes reports (docs/sim2real.md).
"""

__all__: list[str] = []
