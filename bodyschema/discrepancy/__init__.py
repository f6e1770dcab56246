"""Sim-to-real discrepancy analysis: what the simulation gets wrong about a measured IMU, and why.

Given a reference motion (motion capture of a rigid body, or a robot's joint angles through its
model) and what the IMU really read, this package predicts what the IMU *should* read under the
simulator's model, analyses the residual's structure, and selects — on held-out time blocks — the
error effects (:data:`EFFECT_NAMES`) that explain it, with parameters, uncertainties and gains.

* :mod:`~bodyschema.discrepancy.effects` — the effect library (parameters, signatures, prediction
  through :mod:`bodyschema.imu_effects`);
* :mod:`~bodyschema.discrepancy.fit` — data preparation and least-squares fits on sample subsets;
* :mod:`~bodyschema.discrepancy.residuals` — residual structure and noise;
* :mod:`~bodyschema.discrepancy.selection` — the greedy held-out selection (:func:`analyze`, its
  settings :class:`AnalyzerOptions`);
* :mod:`~bodyschema.discrepancy.separability` — which effects a recording can tell apart; those it
  cannot are named jointly (``"acc_bias or gravity"``) with their joint value;
* :mod:`~bodyschema.discrepancy.report` — the result as data (the discrepancy JSON, docs/design.md,
  'Discrepancy JSON');
* :mod:`~bodyschema.discrepancy.network_gravity` — the robot gravity case: the paper's sensor networks
  without gravity (Eq. 11) against with it (Eq. 24), the cause named for the difference and the
  topology each form learns (imported on its own: it needs torch).
"""

from bodyschema.discrepancy.effects import EFFECT_NAMES, EFFECTS, FITTED_EFFECTS, Effect, Params, predict
from bodyschema.discrepancy.fit import Problem, fit_params, prepare
from bodyschema.discrepancy.report import Cause, DiscrepancyReport, JointCause
from bodyschema.discrepancy.residuals import noise_std, residual_structure
from bodyschema.discrepancy.selection import (
    AnalyzerOptions,
    DiscrepancyAnalyzer,
    analyze,
    analyze_recording,
    reference_of,
)

__all__ = [
    "EFFECTS",
    "EFFECT_NAMES",
    "FITTED_EFFECTS",
    "AnalyzerOptions",
    "Cause",
    "DiscrepancyAnalyzer",
    "DiscrepancyReport",
    "Effect",
    "JointCause",
    "Params",
    "Problem",
    "analyze",
    "analyze_recording",
    "fit_params",
    "noise_std",
    "predict",
    "prepare",
    "reference_of",
    "residual_structure",
]
