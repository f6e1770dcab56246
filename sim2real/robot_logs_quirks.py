"""What a robot's own log does that a simulator's does not, measured from its numbers (never assumed).

* **Held values**: a sensor sampled slower than the log's clock repeats its last value on the rows in
  between. A row counts as repeated when every channel of the stream equals the previous row exactly;
  the stream's true update rate is then its changes per second.
* **Irregular stamps**: median, smallest and largest step, jitter (standard deviation of the steps) and
  gaps (steps over ``gap_factor`` median steps).
* **Encoder quantum**: the smallest step of each joint's position above the resolution of the stored
  numbers (averaged over the steps that size), the counts per turn it makes, and whether it is
  ``2π / 2**bits`` for some ``bits`` (a geared encoder's is not: 2^14 counts through a 6.33:1 gear).

Example
-------
>>> import numpy as np
>>> held = np.repeat(np.arange(500.0), 2)[:, None]  # updated on every second row
>>> r = repeated_rows(held, np.arange(1000) * 0.0025)
>>> r["repeated_rows"], round(r["update_rate_hz"])
(500, 200)
>>> q = np.round(np.sin(np.linspace(0, 3, 500)) / (2 * np.pi / 4096)) * (2 * np.pi / 4096)
>>> enc = encoder_quantum(q, resolution=np.spacing(1.0))
>>> enc["bits"], enc["matches_power_of_two"]
(12, True)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["QUANTUM_RESOLVED", "QUANTUM_SCALE_TOL", "clock_report", "encoder_quantum", "repeated_rows"]

#: Relative deviation of a measured quantum from ``2π / 2**bits`` still called a match: firmware turns
#: counts into units with a factor written to five or six significant digits (4096/360 = 11.3778), so a
#: true 12-bit quantum can come out a few parts per million off (the iCub's: 2.4e-6). 1e-4 is a factor
#: given to five digits; the nearest other candidates are a factor of two away.
QUANTUM_SCALE_TOL = 1e-4


#: The log must resolve a quantum to this relative precision before a match is claimed or denied
#: (``matches_power_of_two`` is None otherwise): neighbouring candidates differ by a factor of two, and a
#: 5 % uncertainty leaves no two of them, nor a geared quantum between them, confusable.
QUANTUM_RESOLVED = 0.05


def repeated_rows(v: np.ndarray, t: np.ndarray) -> dict[str, Any]:
    """How often a stream repeats its previous row exactly, and its update rate from its changes.

    ``v`` is (T, ...) on stamps ``t`` (T,). ``update_rate_hz`` = rows that changed / duration: a
    200 Hz sensor on a 400 Hz log repeats half its rows and changes 200 times a second.
    """
    v = np.asarray(v).reshape(np.shape(v)[0], -1)
    steps = v.shape[0] - 1
    if steps < 1:
        return {"repeated_rows": 0, "repeat_fraction": 0.0, "update_rate_hz": None}
    same = np.all(v[1:] == v[:-1], axis=1)
    n = int(same.sum())
    duration = float(t[-1] - t[0])
    rate = (steps - n) / duration if duration > 0 else None
    return {
        "repeated_rows": n,
        "repeat_fraction": n / steps,
        "update_rate_hz": rate,
    }


def clock_report(t: np.ndarray, gap_factor: float = 1.5) -> dict[str, Any]:
    """Step statistics of one clock's stamps (s): median, min, max, jitter (std), and gaps.

    A gap is a step over ``gap_factor`` median steps (1.5: a single dropped sample doubles a step).
    """
    d = np.diff(np.asarray(t, dtype=np.float64))
    if d.size == 0:
        return {"samples": int(np.shape(t)[0]), "rate_hz": None}
    med = float(np.median(d))
    gaps = d[d > gap_factor * med]
    return {
        "samples": int(d.size + 1),
        "duration_s": float(t[-1] - t[0]),
        "rate_hz": 1.0 / med if med > 0 else None,
        "median_step_s": med,
        "min_step_s": float(d.min()),
        "max_step_s": float(d.max()),
        "jitter_std_s": float(d.std()),
        "gaps": {
            "factor": gap_factor,
            "count": int(gaps.size),
            "largest_s": float(gaps.max()) if gaps.size else None,
            "first_index": int(np.flatnonzero(d > gap_factor * med)[0] + 1) if gaps.size else None,
        },
    }


def encoder_quantum(q: np.ndarray, resolution: float) -> dict[str, Any]:
    """The quantum of one joint's positions (rad): the mean of its smallest steps, and the power of two it
    matches, if any.

    ``resolution`` is how finely the log stores the numbers (rad): a step is the difference of two stored
    values, each off by up to half of it, so steps at or below ``resolution`` are rounding, not motion,
    and a measured quantum is known to ± ``resolution``. It matches ``2π / 2**bits`` when it is within
    that, or within :data:`QUANTUM_SCALE_TOL` relative, of it; when ``resolution`` is over
    :data:`QUANTUM_RESOLVED` of the quantum the log cannot tell, and ``matches_power_of_two`` is None.
    """
    s = np.abs(np.diff(np.asarray(q, dtype=np.float64)))
    s = s[s > resolution]
    out: dict[str, Any] = {"quantum_rad": None, "resolution_rad": float(resolution), "counts_per_turn": None}
    out.update({"bits": None, "relative_error": None, "matches_power_of_two": False})
    if s.size == 0:
        return out
    # The one-count steps, each known to ± resolution: their mean is the quantum (a 6-digit log prints a
    # 60.6 µrad step as 60 or 61 µrad).
    quantum = float(s[s <= s.min() + resolution].mean())
    bits = round(math.log2(2 * math.pi / quantum))
    ideal = 2 * math.pi / 2**bits
    rel = quantum / ideal - 1.0
    tol = max(QUANTUM_SCALE_TOL, resolution / ideal)
    out.update(
        {
            "quantum_rad": quantum,
            "counts_per_turn": 2 * math.pi / quantum,
            "bits": int(bits),
            "relative_error": rel,
            "matches_power_of_two": bool(abs(rel) <= tol) if tol <= QUANTUM_RESOLVED else None,
        }
    )
    return out
