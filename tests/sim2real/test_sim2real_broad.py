"""Hide known effects in *measured* data (BROAD trials): the analysis must name exactly them, on top.

BROAD: Laidig, Caruso, Cereatti, Seel, "BROAD—A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7), 2021, CC BY 4.0. The real IMU already differs from its motion capture (a
time offset of about one sample, a lever arm of about 8 mm, ...), so every trial carries its own
expected set of named effects and its own values. A hidden-effect case asserts the *exact* set
(the trial's set plus the injected effects, nothing else) and each injected effect's fitted value
against the trial's own value combined with the injected one.

Each analysis of a whole trial (about 3 min of data) takes 2-7 s on this machine; the analyses are
shared between the asserts through module-scoped fixtures.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema.discrepancy import DiscrepancyReport, analyze, analyze_recording, reference_of
from bodyschema.discrepancy.hidden import hide_effect
from bodyschema.recording import Recording
from sim2real.broad import load_broad
from sim2real.report import simulate_readings
from tests.broad_data import broad_marks, broad_trial

#: Slow rotations with rests between them: small residuals, so biases, scales and a gravity tilt show.
SLOW = "05_undisturbed_slow_rotation_with_breaks_B"
#: Fast rotations: rates up to several rad/s, so a gyro scale shows (and a small gyro bias does not).
FAST = "07_undisturbed_fast_rotation_B"
#: Tapping: the one trial whose lever arm is not named.
TAP = "25_disturbed_tapping_B"

pytestmark = broad_marks(SLOW, FAST, TAP)

#: What each untouched whole trial names (``analyze_recording`` with its defaults), measured on
#: 2026-11-25 by running the analysis on the trial with nothing added. ``noise`` is named on every
#: real trial: the sensor's white noise is far above the analysis's noise floor (1e-4 rad/s, 1e-3
#: m/s²). The session-B gyro bias, about 0.4 deg/s, explains 2.5 % of what the time offset and the
#: lever arm leave of the slow trial's gyro residual; the fast trial has a gyro scale error of
#: 0.2-0.5 % per axis (8 % of its remaining gyro residual), the tapping trial a small one too. The
#: tapping trial's gravity error cannot be told from an accelerometer bias there (its attitude
#: hardly changes): it is named jointly, ``"acc_bias or gravity"`` (re-measured on 2026-11-26).
TRIAL_EFFECTS: dict[str, frozenset[str]] = {
    SLOW: frozenset({"time_offset", "lever_arm", "gyro_bias", "noise"}),
    FAST: frozenset({"time_offset", "lever_arm", "gyro_scale", "noise"}),
    TAP: frozenset({"time_offset", "gyro_bias", "lever_arm", "acc_bias or gravity", "gyro_scale", "noise"}),
}

#: A trial's own effects at the edge of naming: each explains about 1 % of what the model leaves of
#: its channel, against ``min_gain``'s 0.5 %, and on the slow trial several of them share one small
#: accelerometer residual (1.6 mg): an acc bias or a 0.1 degree mounting rotation, which take it in
#: turns depending on what else the model holds. Measured on the untouched trials and the cases
#: below, each of which names none, one or the other (the fast trial's session gyro bias, 0.8 %, and
#: an acc scale, 0.6 %, likewise). Allowed, not required; anything else beyond the trial's set and
#: the injected effects is an extra name.
BORDERLINE: dict[str, frozenset[str]] = {
    SLOW: frozenset({"acc_bias", "mounting_rotation"}),
    FAST: frozenset({"gyro_bias", "acc_scale"}),
    TAP: frozenset(),
}

#: The trial's own value of each effect a case injects, measured on 2026-11-24 on the untouched
#: trial (time offsets, lever arms and FAST's gyro scale again on 2026-11-25, with the gyro bias and
#: scale named and the delay fitted on a cubic interpolation; time offsets and FAST's lever arm again
#: on 2026-11-27, with the channels' weights taken aligned): for the named
#: effects the null analysis's fit; for the others a least-squares fit with that
#: effect forced in beside the named ones (``fit_params``), below what the selection accepts. A
#: hidden effect's fitted value is expected at its own value combined with the injected one (added
#: for offsets and vectors, multiplied for gains, composed for rotations). The session-B gyro bias
#: here, (3.9, 2.3, -4.2) mrad/s, is the one trials 02, 11 and 14 of the same session name.
OWN: dict[str, dict[str, object]] = {
    SLOW: {
        "time_offset": 0.00393,
        "lever_arm": [0.00044, -0.00316, 0.00765],
        "gyro_bias": [0.00391, 0.00230, -0.00416],
        "acc_bias": [0.01565, -0.00404, 0.00791],
        "acc_scale": [1.00011, 0.99935, 1.00081],
        "gravity": [-0.01192, 0.00622, -9.81893],
        "mounting_rotation": [-0.00030, -0.00160, 0.00018],
    },
    FAST: {
        "time_offset": 0.00416,
        "lever_arm": [0.00070, -0.00173, 0.00776],
        "gyro_scale": [1.00517, 1.00212, 1.00336],
        # the session-B bias again, named on the untouched trial (2026-11-25) at the edge of naming
        "gyro_bias": [0.00411, 0.00307, -0.00450],
        # std at the recorded rate: gyro rad/s, then acc m/s²
        "noise": [0.03574, 0.01736, 0.03161, 0.13922, 0.15607, 0.23022],
    },
}

#: How far a fitted value may lie from the expected one: a measured error budget. Each case was run
#: once and its largest deviation is in the comment; the tolerance is several times that, and no
#: tighter than what separates trials of one session (the session-B gyro bias varies by 0.3 mrad/s
#: between trials 02, 11 and 14). The time offset's is wider. A delay alone comes back whole (25 ms
#: hidden in FAST: within 0.01 ms, see the test of a bias behind a delay), since the channels'
#: weights are taken with each channel aligned (bodyschema.discrepancy.fit, ``_aligned_rms``); taken
#: at offset zero they had moved with the delay, and 0.46 ms of it was lost. But the weights are each
#: channel's residual against the bare model, so a large effect the fit then explains in one channel
#: still lowers that channel's weight: beside a 6.4 deg/s gyro bias in SLOW, 25 ms comes out 0.75 ms
#: short, pulled to the accelerometer's preferred offset. 1 ms holds that.
TOL = {
    "time_offset": 1e-3,  # s
    "gyro_bias": 1e-3,  # rad/s per axis; measured within 0.15 mrad/s (alone and in both pairs)
    "acc_bias": 0.01,  # m/s² per axis; measured within 0.04 mm/s²
    "gyro_scale": 2e-3,  # gain per axis; measured within 2e-5
    "acc_scale": 2e-3,  # gain per axis; measured within 7e-5 (alone and paired)
    "mounting_rotation": 0.2,  # degrees; measured 0.043
    "lever_arm": 1e-3,  # m per axis; measured within 0.08 mm
    "gravity": 0.01,  # m/s² per axis; measured within 0.21 mm/s²
    "noise": 0.1,  # relative, on the added std; measured within 0.5 %
}

DEG = np.pi / 180.0
#: A 1.8 degree tilt of the world vertical (1.5 degrees about x, -1 about y), magnitude kept.
TILTED_GRAVITY = Rotation.from_rotvec([1.5 * DEG, -1.0 * DEG, 0.0]).apply([0.0, 0.0, -9.81]).tolist()
Case = list[tuple[str, dict[str, object]]]

#: The hidden-effect cases: (trial, [(effect, injected params), ...]), fixed magnitudes and signs,
#: injected in the order listed. The last is small effects a user hid in SLOW and an earlier
#: selection missed (it weighed a gyro effect against both channels' residual, tested it with a
#: t-test over 8 blocks and stopped after two failed candidates): a 1.3 deg/s gyro bias beside a 3 %
#: acc scale on one axis. The other such case is its own test below.
CASES: dict[str, tuple[str, Case]] = {
    "time_offset": (FAST, [("time_offset", {"seconds": 0.025})]),
    "gyro_bias": (SLOW, [("gyro_bias", {"vector": [0.09, -0.0525, 0.0375]})]),  # 6.4 deg/s
    "acc_bias": (SLOW, [("acc_bias", {"vector": [0.2, -0.1, 0.15]})]),
    "gyro_scale": (FAST, [("gyro_scale", {"matrix": [1.02, 0.98, 1.01]})]),
    "acc_scale": (SLOW, [("acc_scale", {"matrix": [1.03, 0.98, 1.0]})]),
    "mounting_rotation": (SLOW, [("mounting_rotation", {"rotvec": [3 * DEG, -2 * DEG, 4 * DEG]})]),
    "lever_arm": (SLOW, [("lever_arm", {"meters": [0.02, -0.015, 0.01]})]),
    "gravity": (SLOW, [("gravity", {"vector": TILTED_GRAVITY})]),
    "noise": (FAST, [("noise", {"gyro_density": [3e-3] * 3, "acc_density": [3e-2] * 3})]),
    "time_offset+gyro_bias": (
        SLOW,
        [("gyro_bias", {"vector": [0.09, -0.0525, 0.0375]}), ("time_offset", {"seconds": 0.025})],
    ),
    "gyro_bias+acc_scale": (
        SLOW,
        [("gyro_bias", {"vector": [0.09, -0.0525, 0.0375]}), ("acc_scale", {"matrix": [1.03, 0.98, 1.0]})],
    ),
    "small gyro_bias+acc_scale": (
        SLOW,
        [("gyro_bias", {"vector": [0.012, -0.02, 0.0]}), ("acc_scale", {"matrix": [1.0, 1.03, 1.0]})],
    ),
}


_RECORDINGS: dict[str, Recording] = {}


def _trial(name: str) -> Recording:
    """Each trial is read once per module (reading one takes about a second)."""
    if name not in _RECORDINGS:
        _RECORDINGS[name] = load_broad(broad_trial(name))
    return _RECORDINGS[name]


@pytest.fixture(scope="module", params=list(TRIAL_EFFECTS))
def untouched(request: pytest.FixtureRequest) -> tuple[str, DiscrepancyReport]:
    """The analysis of one whole trial with nothing added (the trial's null case)."""
    return request.param, analyze_recording(_trial(request.param))


@pytest.fixture(scope="module", params=list(CASES))
def hidden(request: pytest.FixtureRequest) -> tuple[str, Case, DiscrepancyReport]:
    """One case: the trial with its effects injected in order, and the analysis of the result."""
    trial, effects = CASES[request.param]
    rec = _trial(trial)
    gyro, acc = rec.gyro[:, 0], rec.acc[:, 0]
    rng = np.random.default_rng(20261124)  # only the noise case draws
    for effect, params in effects:
        gyro, acc = hide_effect(effect, params, rec.t, gyro, acc, rec.ref_quat, rng)
    return trial, effects, analyze_recording(replace(rec, gyro=gyro[:, None], acc=acc[:, None]))


def _names(rep: DiscrepancyReport) -> set[str]:
    """What a report names: its effects named alone and its joint names (``"acc_bias or gravity"``)."""
    return set(rep.names) | set(rep.joint_names)


def test_an_untouched_trial_names_exactly_its_own_effects(untouched) -> None:
    trial, rep = untouched
    assert TRIAL_EFFECTS[trial] <= _names(rep) <= TRIAL_EFFECTS[trial] | BORDERLINE[trial]
    assert rep.names[0] == "time_offset"  # the strongest cause of every trial: about one sample
    assert 0.0036 < rep.params["time_offset"]["seconds"] < 0.0044  # 3.8-4.2 ms over the 15 trials
    if trial in OWN:
        own = OWN[trial]
        assert rep.params["time_offset"]["seconds"] == pytest.approx(own["time_offset"], abs=5e-5)
        assert np.allclose(rep.params["lever_arm"]["meters"], own["lever_arm"], atol=5e-5)
    assert rep.held_out["gain"] > 0.3
    assert "Laidig" in rep.meta["attribution"]


def _expected(trial: str, effect: str, injected: dict[str, object]) -> np.ndarray:
    """Where the fitted value of ``effect`` should land: the trial's own value with the injected one."""
    own = OWN[trial]
    if effect == "time_offset":
        return np.array([own[effect] + injected["seconds"]])
    if effect in ("gyro_bias", "acc_bias"):
        return np.add(own[effect], injected["vector"])
    if effect == "lever_arm":
        return np.add(own[effect], injected["meters"])
    if effect in ("gyro_scale", "acc_scale"):
        return np.multiply(own[effect], injected["matrix"])
    if effect == "gravity":
        return np.add(own[effect], np.subtract(injected["vector"], [0.0, 0.0, -9.81]))
    raise KeyError(effect)


def _check_value(trial: str, effect: str, injected: dict[str, object], rep: DiscrepancyReport) -> None:
    got = rep.params[effect]
    if effect == "mounting_rotation":
        # the injected rotation applies on top of the trial's own (tiny) misalignment
        want = Rotation.from_rotvec(injected["rotvec"]) * Rotation.from_rotvec(OWN[trial][effect])
        err = Rotation.from_rotvec(got["rotvec"]).inv() * want
        assert np.degrees(err.magnitude()) < TOL[effect]
    elif effect == "noise":
        # white noise adds in power: what the fit sees beyond the trial's own std is the injected std
        added = np.sqrt(np.square(got["std"]) - np.square(OWN[trial]["noise"]))
        density = np.concatenate([injected["gyro_density"], injected["acc_density"]])
        want = density * np.sqrt(got["rate_hz"])
        assert np.allclose(added, want, rtol=TOL[effect]), (added, want)
    else:
        value = np.ravel(next(iter(got.values())))
        want = _expected(trial, effect, injected)
        assert np.allclose(value, want, atol=TOL[effect], rtol=0.0), f"{effect}: fitted {value}, want {want}"


@pytest.mark.slow
def test_hidden_effects_are_named_exactly_and_measured(hidden) -> None:
    trial, effects, rep = hidden
    injected = {e for e, _ in effects}
    expected = TRIAL_EFFECTS[trial] | injected
    named = _names(rep)
    assert expected <= named <= expected | BORDERLINE[trial], f"injected {sorted(injected)} in {trial}"
    for effect, params in effects:
        _check_value(trial, effect, params, rep)
        if effect != "noise":
            assert rep.cause(effect).p_value < 0.01


def test_the_simulated_twin_of_a_trial_names_no_fitted_effect() -> None:
    """The simulator's ideal IMU driven by the trial's own motion capture: the null of the simulation.

    Measured: no fitted effect is named and nothing of the residual is explained; ``noise`` is named
    (acc std 2.3-3.8 m/s²), because the ideal readings of raw motion capture carry its twice-
    differentiated position noise above the motion band. What remains in the band is the
    accelerometer's low-pass taken in the world frame on one side and in the sensor frame on the
    other: 0.010 m/s² rms on this slow trial.
    """
    rec = _trial(SLOW)
    g, a = simulate_readings(reference_of(rec, None), "ideal")
    rep = analyze(reference_of(rec), g, a, rec.extra["ref_valid"])
    assert rep.names == ["noise"]
    assert rep.held_out["score_after"] == rep.held_out["score_before"]
    assert rep.residual_before["gyro_rms"] < 1e-6  # rad/s; measured 4e-9, round-off of the filters
    assert rep.residual_before["acc_rms"] < 0.02
    assert min(rep.params["noise"]["std"][3:]) > 1.0  # m/s²: the reference's noise, not an IMU's


@pytest.mark.slow
def test_a_small_bias_behind_a_large_delay_is_named() -> None:
    """A 3.1 deg/s gyro bias beside a 25 ms delay on FAST: the delay leaves a gyro residual fifty
    times larger than the bias, against which an earlier selection measured (and missed) it.

    Named and measured: each axis of the expected bias lies inside its 95 % interval (measured within
    0.03 mrad/s). The fit's pull towards "effect absent" once held this bias to 79-84 % of itself
    (bodyschema.discrepancy.fit). The delay came out 0.46 ms short while the channels' weights were
    taken at offset zero (the time offset's tolerance above).
    """
    rec = _trial(FAST)
    rng = np.random.default_rng(0)
    gyro, acc = hide_effect(
        "time_offset", {"seconds": 0.025}, rec.t, rec.gyro[:, 0], rec.acc[:, 0], rec.ref_quat, rng
    )
    bias = np.array([0.0, 0.045, -0.03])
    gyro, acc = hide_effect("gyro_bias", {"vector": bias.tolist()}, rec.t, gyro, acc, rec.ref_quat, rng)
    rep = analyze_recording(replace(rec, gyro=gyro[:, None], acc=acc[:, None]))
    expected = TRIAL_EFFECTS[FAST] | {"gyro_bias"}
    assert expected <= _names(rep) <= expected | BORDERLINE[FAST]
    want = np.add(OWN[FAST]["gyro_bias"], bias)
    lo, hi = np.asarray(rep.cause("gyro_bias").interval).T
    assert np.all((lo < want) & (want < hi)), (lo, want, hi)
    # the delay alone in the gyro channel's way: it comes back whole (0.46 ms short with the channels'
    # weights taken at offset zero); 0.1 ms is ten times the rounding of the trial's own value
    assert rep.params["time_offset"]["seconds"] == pytest.approx(OWN[FAST]["time_offset"] + 0.025, abs=1e-4)
