"""Tuning of the AUKF-FS estimator: ``[estimator]`` with ``[estimator.fuzzy]``.

Declared, read and written with the package's config base
(:mod:`tractionecu.config`).  The measurement noise is not tuning: it comes
from the sensor figures (:class:`~tractionecu.config.SensorSpec`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..config import _naming, from_mapping, load_toml, section, setting, to_toml, validate
from ..errors import ConfigError
from ..model.mucurve import CURVE_SHAPES, SOIL_CLASSES
from ..model.vehicle import N_STATE
from .calibration import CalibrationConfig
from .supervisor import FuzzyConfig


@dataclass(frozen=True)
class EstimatorConfig:
    """Tuning of the AUKF-FS.  Measurement noise is not here: it comes from ``SensorSpec``."""

    # UKF
    alpha: float = setting(1.0, "sigma-point spread α [-] (filterpy MerweScaledSigmaPoints)", 1e-4, 10.0)
    beta: float = setting(2.0, "sigma-point β [-] (2 is optimal for Gaussians)", 0.0, 10.0)
    kappa: float = setting(0.0, "sigma-point κ [-]", -9.0, 100.0)
    max_gap_s: float = setting(2.0, "a gap between steps longer than this restarts the filter [s]", 0.01, 3600.0)
    max_step_s: float = setting(0.02, "longest single prediction step; longer gaps are sub-stepped [s]", 1e-4, 1.0)
    # process noise (tuning)
    q_omega: float = setting(1e-4, "model-error density on each ω [rad²/s³]", 0.0, 1e3)
    q_v: float = setting(1e-4, "model-error density on v [m²/s³]", 0.0, 1e3)
    q_mu: float = setting(1e-3, "random-walk density of each μ [1/s]", 0.0, 10.0)
    q_rho: float = setting(2e-5, "random-walk density of ρ_s [1/s]", 0.0, 10.0)
    input_noise: bool = setting(True, "add the measured-input noise (SensorSpec) to Q")
    # adaptation (paper eqs. 16–17) and fuzzy supervisor
    adaptation: bool = setting(True, "covariance-matching adaptation A_k of Q")
    adapt_window: int = setting(100, "window M of updates for covariance matching [-]", 2, 100000)
    adapt_min: float = setting(0.5, "lower clip of A_k entries [-]", 1e-3, 1.0)
    adapt_max: float = setting(20.0, "upper clip of A_k entries [-]", 1.0, 1e4)
    supervisor: bool = setting(True, "fuzzy-logic supervisor factor f_k on Q")
    adapt_period_s: float = setting(0.1, "period at which A_k and f_k are recomputed [s]", 1e-3, 10.0)
    dynamics_tau_s: float = setting(0.2, "low-pass time constant of |dv/dt|, |dM_d/dt| [s]", 1e-3, 10.0)
    # robustness
    gate_probability: float = setting(1e-4, "false-alarm probability of the per-measurement NIS gate [-] (0 disables)", 0.0, 0.5)
    gate_max_consecutive: int = setting(5, "a measurement gated this many updates in a row is accepted on the next [-]", 0, 100000)
    lost_after_s: float = setting(1.0, "the filter is declared lost and re-initialised after its updates were gated or "
                                       "far outside their χ² bound, or ρ_s sat at its bound while moving, this long [s]; "
                                       "0 disables (estimation/divergence.py)", 0.0, 600.0)
    lost_nis_alpha: float = setting(1e-6, "tail probability of the χ²(dof) bound a NIS must exceed to count towards "
                                          "a lost filter [-]", 1e-15, 0.5)
    direction_min_speed_mps: float = setting(0.2, "wheel-based speed above which the sign of wheel rotation gives the "
                                                  "direction of travel (signs the unsigned GNSS speed); below it the "
                                                  "last direction is held [m/s]", 0.0, 10.0)
    standstill_speed_mps: float = setting(0.2, "below this ground speed ρ_s drops out of eq. 8 and slip is undefined: "
                                               "the estimate is flagged standstill (0x400) and not valid [m/s]",
                                          0.0, 10.0)
    slip_sigma_max: float = setting(0.0125, "largest standard deviation of a wheel's slip, from the filter's σ_v and "
                                            "σ_κ, that the data supports [-]: above it slip is held and flagged "
                                            "(0x2000) and no μ(s) pair goes to the curve (μ and ρ_s keep their own "
                                            "validity); "
                                            "0.0125 keeps the expected absolute error of a supported slip "
                                            "(0.8 σ) within 0.01; 0 disables", 0.0, 1.0)
    slip_avg_max_m: float = setting(10.0, "longest stretch of travel [m] over which a slip whose own σ exceeds "
                                          "slip_sigma_max (creeping, reversing at 1 m/s) may be reported averaged: "
                                          "of the stretches of up to this many metres ending now, in one direction "
                                          "without a standstill, the one whose averaged slip has the smallest σ, if "
                                          "that σ is within slip_sigma_max (status 0x10000 slip_averaged, "
                                          "Estimator._slip_window); 0 disables",
                                    0.0, 1000.0)
    slip_avg_corr_s: float = setting(1.0, "correlation time [s] of the ground-speed error assumed for the σ of an "
                                          "averaged slip: GNSS Doppler speed errors are correlated over about 1 s "
                                          "(the receiver's own tracking and navigation filters); the filter's v error "
                                          "on white 10 Hz GNSS noise decorrelates in 0.2–0.4 s, so this is the "
                                          "conservative figure", 0.01, 100.0)
    mu_min: float = setting(-1.2, "lower bound of μ [-]", -5.0, 0.0)
    mu_max: float = setting(1.2, "upper bound of μ [-]", 0.0, 5.0)
    rho_min: float = setting(0.0, "lower bound of ρ_s [-]", -1.0, 0.0)
    rho_max: float = setting(0.5, "upper bound of ρ_s [-]", 0.0, 5.0)
    # timeouts: max(floor, timeout_periods × the period observed on the bus) (estimation/rates.py)
    wheel_timeout_s: float = setting(0.05, "shortest wheel-speed timeout (floor of the rate-derived one) [s]", 1e-3, 60.0)
    gps_timeout_s: float = setting(0.5, "shortest ground-speed timeout (floor of the rate-derived one) [s]", 1e-3, 60.0)
    torque_timeout_s: float = setting(0.05, "shortest drive-torque timeout (floor of the rate-derived one) [s]", 1e-3, 60.0)
    axle_timeout_s: float = setting(0.1, "shortest front-axle-load timeout (floor of the rate-derived one) [s]", 1e-3, 60.0)
    draft_timeout_s: float = setting(0.1, "shortest draft-force timeout (floor of the rate-derived one) [s]", 1e-3, 60.0)
    timeout_periods: float = setting(3.0, "a stream times out after this many of its observed periods without a sample "
                                          "(one lost sample plus jitter of up to a period never trips it); longer "
                                          "intervals are gaps, not the rate [-]", 1.5, 100.0)
    rate_window: int = setting(16, "inter-arrival intervals per median of a stream's observed period; the configured "
                                   "SensorSpec rate is used until the first median [-]", 3, 10000)
    # initial uncertainty and convergence
    sigma_v0: float = setting(0.2, "initial standard deviation of v [m/s]", 1e-6, 100.0)
    sigma_mu0: float = setting(0.1, "initial standard deviation of μ [-]", 1e-6, 10.0)
    rho_s0: float = setting(0.06, "initial ρ_s [-]", 0.0, 1.0)
    sigma_rho0: float = setting(0.05, "initial standard deviation of ρ_s [-]", 1e-6, 10.0)
    conv_sigma_mu: float = setting(0.01, "converged when every σ_μ is below this [-]", 1e-6, 10.0)
    conv_sigma_rho: float = setting(0.01, "converged when σ_ρ is below this [-]", 1e-6, 10.0)
    conv_min_s: float = setting(1.0, "never converged earlier than this after start [s]", 0.0, 3600.0)
    conv_exit_factor: float = setting(1.5, "hysteresis of the convergence test: a converged filter is declared not "
                                           "converged only when a σ_μ or σ_ρ exceeds this multiple of its bound; "
                                           "between two samples of a 10–20 Hz wheel-speed stream the filter's σ_μ "
                                           "grows by ×1.2–1.4 and comes back at the next update, which a single "
                                           "bound turned into a flickering not_converged bit (1: no hysteresis) [-]",
                                      1.0, 10.0)
    # curve parameter a (paper section 3.2)
    soil_classes: tuple[str, ...] = setting(("stubble",), "surface classes (shapes p, α1, α2) to fit; first = default")
    curve_tau_s: float = setting(3.0, "smoothing time constant of a [s]", 1e-3, 3600.0)
    curve_min_mu: float = setting(0.15, "pairs with |μ| below this are skipped as ill-conditioned (low slip) [-]", 0.0, 2.0)
    curve_min_slip: float = setting(0.005, "pairs with |s| below this are skipped [-]", 0.0, 0.5)
    curve_min_speed_mps: float = setting(0.5, "no curve update below this speed [m/s]", 0.0, 50.0)
    curve_period_s: float = setting(0.1, "period of the curve update [s]", 1e-3, 10.0)
    curve_class_tau_s: float = setting(30.0, "forgetting time constant of the class evidence [s]", 1e-3, 1e6)
    curve_switch_min_delta: float = setting(10.0, "class switch needs the new class's log-likelihood this much better [nats]", 0.0, 1e9)
    curve_slip_corr_s: float = setting(0.5, "correlation time of the slip error for the class evidence [s]", 1e-3, 1e3)
    curve_shape: bool = setting(True, "identify the μ(s) shape per soil segment once its slips span curve_shape_min_span (False: the one-parameter class path only)")
    curve_shape_min_span: float = setting(0.04, "slip span of a soil segment's pairs the shape fit needs [-]", 0.005, 1.0)
    machine_curve_prior: str = setting("", "machine-level estimator only (mechanical / power-split drivetrain): the one "
                                           "μ(s) shape its (μ, s) pairs are fitted with: '' the soil_classes, 'd497' the "
                                           "ASABE D497.7 slip term 1 − e^(−7.5 s) (estimation/machine_curve.py), or a class")
    curve_shape_load: bool = setting(True, "fit the μ(s) curve's load dependence (1 + q (F_z/F_z,ref − 1)) on the fit's load groups where the wheels' loads differ, kept where q is significant and pays by BIC (False: one curve for every load)")
    carcass_ring_tau_s: float = setting(2.0, "with a declared tyre carcass whose mode the wheel-speed rate cannot "
                                              "follow (the carcass term off, Estimator._relax): time constant of the "
                                              "innovation statistics that estimate the mode's variance in the "
                                              "wheel-speed samples, which R_ω then takes in (Estimator._ring_noise; "
                                              "0: off) [s]", 0.0, 600.0)
    smoother_lag_s: float = setting(0.05, "fixed-lag smoothing of the reported μ and ρ_s (estimation/smoother.py): each "
                                          "estimate is revised by the steps up to this much later (unscented RTS) "
                                          "and delivered that much later; 0: the filter's own estimates at once [s]",
                                    0.0, 1.0)
    # reported uncertainty (estimation/uncertainty.py)
    systematic_uncertainty: bool = setting(True, "add the sensor tolerances (SensorSpec *_tol_*) to the reported σ of "
                                                 "μ and ρ_s and the GNSS latency bound to the GNSS speed noise")
    fuzzy: FuzzyConfig = section(FuzzyConfig, "fuzzy supervisor breakpoints ([estimator.fuzzy])")
    calibration: CalibrationConfig = section(CalibrationConfig, "rolling-radius self-calibration "
                                                                "([estimator.calibration], estimation/calibration.py)")

    def __post_init__(self) -> None:
        validate(self, "estimator")
        if not self.soil_classes:
            raise ConfigError("estimator.soil_classes: at least one class is needed")
        for c in self.soil_classes:
            if c not in SOIL_CLASSES:
                raise ConfigError(f"estimator.soil_classes: unknown class {c!r} (known: {', '.join(SOIL_CLASSES)})")
        if self.machine_curve_prior not in ("", *CURVE_SHAPES, *SOIL_CLASSES):
            raise ConfigError(f"estimator.machine_curve_prior: unknown {self.machine_curve_prior!r} "
                              f"(known: '', {', '.join([*CURVE_SHAPES, *SOIL_CLASSES])})")
        if self.alpha ** 2 * (N_STATE + self.kappa) <= 0:
            raise ConfigError("estimator.kappa: α²(n+κ) must be > 0")
        if self.mu_min >= self.mu_max:
            raise ConfigError(f"estimator.mu_min = {self.mu_min} must be < estimator.mu_max = {self.mu_max}")
        if self.rho_min >= self.rho_max:
            raise ConfigError(f"estimator.rho_min = {self.rho_min} must be < estimator.rho_max = {self.rho_max}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "EstimatorConfig":
        """Build from a TOML table (``[estimator]`` with optional ``[estimator.fuzzy]``, ``[estimator.calibration]``)."""
        return from_mapping(cls, data, "estimator")

    def to_toml(self) -> str:
        """TOML text with ``[estimator]``, ``[estimator.fuzzy]`` and ``[estimator.calibration]`` tables, each key
        with its doc."""
        return to_toml(self, "estimator")


def load_estimator_config(path: str | Path) -> EstimatorConfig:
    """Read an estimator TOML file (``[estimator]`` table, or its keys at the top level).  Keys or tables
    beside an ``[estimator]`` table are an error naming them (``q_mu`` above the table was dropped, the
    default in force and nothing said), as a key above ``[vehicle]`` is in a vehicle file."""
    data = load_toml(path, "configuration")
    with _naming(path):         # "estimator.q_mu = -1.0 is outside ..." named no file
        if "estimator" not in data:
            return EstimatorConfig.from_mapping(data)
        other = sorted(k for k in data if k != "estimator")
        if other:
            raise ConfigError(f"{path}: {', '.join(other)} beside the [estimator] table: put the estimator's keys "
                              "inside [estimator] (or all at the top level, without the table)")
        return EstimatorConfig.from_mapping(data["estimator"])
