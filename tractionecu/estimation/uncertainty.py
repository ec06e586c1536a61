"""Systematic uncertainty of μ and ρ_s from the configured sensor tolerances.

The filter's covariance P describes the random errors it models (noise in
R and Q).  Sensors also carry systematic errors that a calibration leaves
inside a tolerance: a gain and a zero offset of the drive torques and the
load pins, a latency of the GNSS speed, and the tyre's rolling radius.  A
constant error of that kind is not identifiable from the data (eqs. 2 and 8
absorb it into μ and ρ_s), so P cannot contain it, and a band built from P
alone is overconfident on a real machine.  The estimator therefore reports

    σ_μ,i = √(P_μi + u_μ,i²),      σ_ρs = √(P_ρs + u_ρs²),

with u the propagation of the tolerances (:class:`~tractionecu.config.SensorSpec`)
through the steady-state forms of the paper's equations.  The filter's own
P, its gain and its estimates are not changed.  Each tolerance ±b is a
rectangular distribution with standard uncertainty b/√3 (GUM, JCGM
100:2008, 4.3.7); independent contributions add in quadrature.

μ per wheel (eq. 2 at ω̇ ≈ 0, eq. 4): μ_i + ρ_t = M_i / (r_i F_z,i) =: c_i, so

    u_μ,i² = c_i² (u_g² + u_r,axle² + (u_Fzf / (2 F_z,i))²) + (u_M0 / (r_i F_z,i))²

- torque gain δ: Δμ_i = δ c_i (almost one to one: c ≈ μ);
- rolling radius ε (the tyre tolerance, or the self-calibration's interval
  once applied, :mod:`.calibration`): Δμ_i = −ε c_i;
- front-axle load error ΔF_zf (offset ⊕ gain·F_zf): each front wheel
  carries F_zf/2 and each rear wheel (mg − F_zf)/2, so
  ΔF_z,i = ±ΔF_zf/2 and Δμ_i = ∓c_i ΔF_zf / (2 F_z,i);
- torque offset ΔM: Δμ_i = ΔM / (r_i F_z,i);
- the line of pull β (``pull_angle_deg``, bound ``pull_angle_tol_deg``):
  a rear wheel's load F_dx tan β/2 is off by F_dx Δ(tan β)/2, with
  Δ(tan β) ≈ Δβ/cos² β, in quadrature with the load-pin error of the rear
  wheels;
- the hub reduction's declared efficiency η (``drivetrain.efficiency``,
  the drive torques are η times the reported ones): its relative standard
  uncertainty u_η (``drivetrain.efficiency_tolerance``, already 1σ) acts
  as a torque gain common to the four drives, added to u_g² (0 for the
  paper's machine, which declares η = 1 with tolerance 0).
  (r_d's own dependence on F_z, eq. 9, moves μ by < 0.1 % per 300 N and
  is left out.)

ρ_s (eq. 8 at v̇ ≈ 0 with eq. 2 substituted, ΣF_z,i = mg):
ρ_s m g = Σ M_i / r_i − ρ_t m g − F_dx, so

    u_ρs² = [ (u_g Σ|M_i/r_i|)² + Σ_axle (u_r,axle Σ_axle |M_i/r_i|)² + Σ_i (u_M0/r_i)²
              + u_D0² + (u_Dg F_dx)² ] / (m g)²

- the torque gains of the four drives are taken as fully correlated (same
  motor model, same temperature), the conservative choice for a sum;
  their offsets as independent; the radius error as common to an axle;
- a draft offset ΔF maps into ρ_s as ΔF/(m g): with the implement always
  in the ground, ρ_s and a draft zero offset cannot be told apart;
- the front-axle load drops out of ρ_s (the loads always sum to m g).

GNSS latency is not a constant error but one proportional to the
acceleration: a speed reported up to τ late is off by up to τ·v̇.  It is
added to the measurement noise of the GNSS speed (the noise model, so the
filter itself weights the speed less while accelerating):
R_v += (τ v̇)²/3, the mean square of τ·v̇ over τ uniform in [0, τ_max].

Status
------
:data:`~tractionecu.estimation.estimator.UNVERIFIED` is set while the
systematic part is the larger part of the reported variance of any μ_i or
of ρ_s: the stated uncertainty then rests on tolerance bounds (sensor
calibrations, the tyre's radius, the draft zero) that the data cannot
check, not on what the filter has measured.
"""

from __future__ import annotations

import math

from ..config import G, SensorSpec, VehicleParams

_SQRT3 = math.sqrt(3.0)


class SystematicUncertainty:
    """u_μ,i² and u_ρs² from the sensor tolerances (module doc)."""

    def __init__(self, sensors: SensorSpec, vehicle: VehicleParams) -> None:
        sp = sensors
        self.u_g = sp.torque_gain_tol_rel / _SQRT3
        dtr = getattr(vehicle, "drivetrain", None)
        self.u_eta = float(dtr.efficiency_tolerance) if dtr is not None and not dtr.engine_driven else 0.0
        self.tan_pull = math.tan(math.radians(vehicle.pull_angle_deg))
        tol = getattr(vehicle, "pull_angle_tol_deg", 0.0)
        c = math.cos(math.radians(vehicle.pull_angle_deg))
        self.u_tan = math.radians(tol) / _SQRT3 / (c * c)       # standard uncertainty of tan β [-]
        self.u_m0 = sp.torque_offset_tol_nm / _SQRT3
        self.u_a0 = sp.axle_offset_tol_n / _SQRT3
        self.u_ag = sp.axle_gain_tol_rel / _SQRT3
        self.u_d0 = sp.draft_offset_tol_n / _SQRT3
        self.u_dg = sp.draft_gain_tol_rel / _SQRT3
        self.u_r = sp.rolling_radius_tol_rel / _SQRT3
        self.lat2_3 = sp.gps_latency_tol_s ** 2 / 3.0
        self.weight = vehicle.weight_n
        self.mg = vehicle.mass_kg * G

    def gnss_latency_var(self, accel: float) -> float:
        """Added variance of the GNSS speed [m²/s²] at acceleration ``accel`` [m/s²]: (τ_max a)²/3."""
        return self.lat2_3 * accel * accel

    def variances(self, md: list[float], fzf: float, fdx: float, rdf: float, rdr: float,
                  ur_f: float, ur_r: float) -> tuple[list[float], float]:
        """(u_μ,i² for the four wheels, u_ρs²) at drive torques ``md`` [N·m], front-axle load ``fzf`` [N],
        draft ``fdx`` [N], rolling radii r_d of a front and a rear wheel [m] and the relative standard
        uncertainties of the radius in use per axle ``ur_f``, ``ur_r`` [-]."""
        ff = 0.5 * fzf
        fr = 0.5 * (self.weight - fzf) if self.tan_pull == 0.0 else 0.5 * ((self.weight - fzf) + fdx * self.tan_pull)
        u_fz = 0.5 * math.sqrt(self.u_a0 ** 2 + (self.u_ag * fzf) ** 2)     # per-wheel load error [N]
        g2 = self.u_g * self.u_g
        if self.u_eta != 0.0:
            g2 += self.u_eta * self.u_eta
        m02 = self.u_m0 * self.u_m0
        var_mu = []
        f_r = [0.0, 0.0]            # Σ|M_i/r_i| per axle
        off2 = 0.0
        for i in range(4):
            front = i < 2
            r = rdf if front else rdr
            fz = ff if front else fr
            ur = ur_f if front else ur_r
            m_r = md[i] / r
            c = m_r / fz
            lz = u_fz / fz
            if not front and self.u_tan != 0.0:
                lz = math.hypot(u_fz, 0.5 * fdx * self.u_tan) / fz
            var_mu.append(c * c * (g2 + ur * ur + lz * lz) + m02 / (r * fz) ** 2)
            f_r[0 if front else 1] += abs(m_r)
            off2 += m02 / (r * r)
        tot = f_r[0] + f_r[1]
        num = ((self.u_g * tot) ** 2 + (self.u_eta * tot) ** 2 + (ur_f * f_r[0]) ** 2 + (ur_r * f_r[1]) ** 2 + off2
               + self.u_d0 ** 2 + (self.u_dg * fdx) ** 2)
        return var_mu, num / (self.mg * self.mg)
