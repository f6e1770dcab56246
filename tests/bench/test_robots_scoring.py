"""How ``bench robots`` scores an injected fault: found only where a finding of the right kind names the
part alone; a finding that leaves the part among rivals the data fit as well is undetermined, not found
and not missed."""

from __future__ import annotations

from types import SimpleNamespace

from bench.robots import _between, _names, _undetermined
from bodyschema.findings import Finding

ALONE = Finding("encoder_fault", joint="l_knee")
RIVALS = Finding("encoder_fault", joint="r_ankle_roll", confidence=0.65, candidates=("joint:r_hip_roll",))


def test_a_part_named_alone_is_found_and_one_among_rivals_is_not() -> None:
    assert _names(ALONE, "l_knee") and not _names(ALONE, "r_knee")
    assert not _names(RIVALS, "r_ankle_roll") and not _names(RIVALS, "r_hip_roll")


def test_a_part_among_rivals_is_undetermined_whichever_the_finding_names() -> None:
    for part in ("r_hip_roll", "r_ankle_roll"):
        why = _between((ALONE, RIVALS), "encoder_fault", part)
        assert why == "encoder_fault on one of r_ankle_roll, r_hip_roll: they fit alike"
    assert _between((ALONE, RIVALS), "encoder_fault", "l_knee") is None  # named alone: no rivals
    assert _between((RIVALS,), "imu_rotated", "r_hip_roll") is None  # another kind
    assert _between((RIVALS,), "encoder_fault", "l_hip_roll") is None  # not among them


def test_only_faults_the_recording_cannot_show_are_excused_as_undetermined() -> None:
    """Point feet (no stance chain, no tilt model): an offset, a mount turn and a flip over the whole
    window cannot show; a flip that begins inside the window jumps, and missing it stays a miss."""
    point = SimpleNamespace(chains=(), tilt=None)
    flat = SimpleNamespace(chains=("a chain",), tilt="a tilt model")
    for name in ("encoder_offset", "imu_rotated", "encoder_sign"):
        assert _undetermined(name, point) and _undetermined(name, flat) is None
    for name in ("encoder_sign mid-window", "encoder_frozen", "imu_silent"):
        assert _undetermined(name, point) is None
