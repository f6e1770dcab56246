"""Which feet are on the ground: from the measured foot forces, and from the kinematics alone.

**From forces.** A foot in the air still reads a force: sensor noise, cable pull, the swinging leg's
inertia, an estimator's error. A foot carries load when its force exceeds what swing reads by more
than noise can explain: ``F > mu_swing + k sigma_swing``, with ``mu``/``sigma`` the median and
MAD-based spread of the swing samples and ``k`` the Gaussian quantile of an accepted false-contact
rate per sample (1e-3: ``k = 3.09``). The swing samples are those below a quarter of the way from
the foot's 2nd to its 98th force percentile (unloaded to fully loaded): a foot sharing the load with
one other carries about half of it, so double support stays above the split. This needs no unit and
no robot weight; raw sensor counts work. Runs shorter than ``min_s`` are merged into their neighbours (a
contact change is a mechanical event, not a sample's noise).

**From kinematics.** A stance foot does not move in the world. Given the base's twist from the
other feet, a foot whose predicted world speed stays below what encoder noise allows is in contact:
:func:`kinematic_contact`.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> f = np.where(np.arange(1000) % 200 < 120, 300.0, 0.0) + rng.normal(0, 5, 1000)
>>> c = force_contacts(f[:, None], rate=100.0)
>>> bool(c.down[:120, 0].all()), bool(c.down[130:190, 0].any()), float(round(c.threshold[0] / 5, 0))
(True, False, 3.0)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

__all__ = ["Contacts", "change_mask", "contact_weights", "force_contacts", "kinematic_contact"]


@dataclass(frozen=True)
class Contacts:
    """``down`` (T, F) bool; per foot ``threshold``, swing ``swing_mu`` and ``swing_sigma`` (force
    units), the false-contact rate ``p_false`` and its quantile ``k``."""

    down: np.ndarray
    threshold: np.ndarray
    swing_mu: np.ndarray
    swing_sigma: np.ndarray
    p_false: float
    k: float

    def to_json(self) -> dict[str, object]:
        return {
            "threshold": self.threshold.tolist(),
            "swing_mu": self.swing_mu.tolist(),
            "swing_sigma": self.swing_sigma.tolist(),
            "p_false": self.p_false,
            "k": self.k,
            "down_fraction": self.down.mean(axis=0).tolist(),
        }


def _clean_runs(x: np.ndarray, min_len: int) -> np.ndarray:
    """``x`` with runs shorter than ``min_len`` samples flipped to their surroundings."""
    out = x.copy()
    if min_len <= 1:
        return out
    edges = np.flatnonzero(np.diff(out.astype(np.int8))) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [len(out)]])
    for s, e in zip(starts, ends, strict=True):
        if e - s < min_len and s > 0 and e < len(out):
            out[s:e] = ~out[s]
    return out


def force_contacts(forces: np.ndarray, rate: float, p_false: float = 1e-3, min_s: float = 0.03) -> Contacts:
    """Contacts from ``forces`` (T, F) (any unit, larger = more load), sampled at ``rate`` Hz."""
    f = np.asarray(forces, dtype=float)
    k = float(norm.isf(p_false))
    F = f.shape[1]
    thr, mu, sig = np.empty(F), np.empty(F), np.empty(F)
    down = np.zeros(f.shape, dtype=bool)
    for j in range(F):
        lo, hi = np.nanpercentile(f[:, j], [2, 98])
        swing = f[:, j][f[:, j] < lo + 0.25 * (hi - lo)]
        mu[j] = float(np.median(swing))
        sig[j] = max(float(1.4826 * np.median(np.abs(swing - mu[j]))), 1e-9 * max(abs(hi - lo), 1.0))
        thr[j] = mu[j] + k * sig[j]
        down[:, j] = _clean_runs(f[:, j] > thr[j], round(min_s * rate))
    return Contacts(down, thr, mu, sig, p_false, k)


def contact_weights(forces: np.ndarray, contacts: Contacts) -> np.ndarray:
    """(T, F) each stance foot's share of the load above its swing level (0 in the air); rows with
    no foot down are 0."""
    load = np.where(contacts.down, np.maximum(forces - contacts.swing_mu, 0.0), 0.0)
    load = np.where(contacts.down & (load <= 0), 1e-9, load)
    tot = load.sum(axis=1, keepdims=True)
    return np.divide(load, tot, out=np.zeros_like(load), where=tot > 0)


def kinematic_contact(
    foot_speed: np.ndarray, noise_std: np.ndarray | float, p_false: float = 1e-3
) -> np.ndarray:
    """(T, F) feet whose predicted world speed (m/s, from the kinematics of the other feet) is below
    ``k`` times the speed noise the encoders put on it, in 3 dimensions (chi with 3 degrees of
    freedom at the miss rate ``p_false``)."""
    from scipy.stats import chi

    return foot_speed < float(chi.isf(p_false, 3)) * np.asarray(noise_std)


def change_mask(down: np.ndarray, rate: float, half_s: float) -> np.ndarray:
    """(T,) samples within ``half_s`` seconds of any foot's contact change (lift-off, touch-down)."""
    change = np.zeros(down.shape[0], dtype=bool)
    change[1:] = np.any(down[1:] != down[:-1], axis=1)
    h = round(half_s * rate)
    return np.convolve(change.astype(float), np.ones(2 * h + 1), mode="same") > 0


def ramp_time(forces: np.ndarray, contacts: Contacts, rate: float) -> float:
    """Median seconds from a touch-down (force above threshold) until the force reaches half the
    foot's loaded level (its 98th percentile): how long a foot takes to settle. Lift-off mirrors it."""
    times = []
    for j in range(forces.shape[1]):
        half = contacts.swing_mu[j] + 0.5 * (np.percentile(forces[:, j], 98) - contacts.swing_mu[j])
        d = contacts.down[:, j]
        for s in np.flatnonzero(~d[:-1] & d[1:]) + 1:
            above = np.flatnonzero(forces[s:, j] >= half)
            end = np.flatnonzero(~d[s:])
            if above.size and (not end.size or above[0] < end[0]):
                times.append(above[0] / rate)
    return float(np.median(times)) if times else 0.0


def transition_weights(down: np.ndarray, rate: float, half_s: float) -> np.ndarray:
    """(T, F) factor in [0, 1] on each foot's stance weight: 0 at its own contact change, rising
    linearly to 1 at ``half_s`` from it (a foot that is landing or leaving rolls and slips)."""
    T, F = down.shape
    out = np.ones((T, F))
    if half_s <= 0:
        return out
    idx = np.arange(T)
    for j in range(F):
        ch = np.flatnonzero(down[1:, j] != down[:-1, j]) + 1
        if ch.size == 0:
            continue
        pos = np.searchsorted(ch, idx)
        left = np.abs(idx - ch[np.clip(pos - 1, 0, ch.size - 1)])
        right = np.abs(ch[np.clip(pos, 0, ch.size - 1)] - idx)
        out[:, j] = np.clip(np.minimum(left, right) / (half_s * rate), 0.0, 1.0)
    return out
