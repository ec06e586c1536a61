"""An independent truth model: a tractor simulator that shares no code and no equation with the package.

``benchmarks/independent_truth.py`` drives it.  It was written from the paper's setting and the physics notes
alone, with numpy and cantools only (the project's DBC for the frame layouts); nothing of ``tractionecu.sim``
or ``tractionecu.model`` is imported, so its figures do not measure the filter against its own equations.

Plant (1 kHz):
- four hub-driven wheels (or a mechanical drive line with one engine, gearbox and a 3 % front lead),
  wheel inertia 60 kg·m²;
- a tanh tyre–soil curve, μ = μ_max (F_z/F_ref)^−0.08 tanh(s/s_c), not the paper's exponential family,
  with its own load dependence; first-order force relaxation (relaxation length 0.3 m);
- quasi-static longitudinal and lateral load transfer (CG height 1.0 m, hitch 0.5 m, line of pull 4°);
- Ackermann ground speeds per wheel in turns;
- draft that varies with depth (±25 % over 40 s) and a coloured disturbance;
- a PI speed controller with a load-proportional torque split and traction control.

Sensors (the datasheet figures the package's own simulator uses, so that the plant and not the noise differs):
- wheel speeds 0.2 % + 0.005 rad/s at 100 Hz, 1 mrad/s quantum;
- drive torques 1 % + 5 N·m, 2 N·m quantum;
- load pins 300 N, 5–10 N quantum;
- GNSS at 10 Hz: Doppler velocity 0.05 m/s per axis (ZED-F9P), so the course carries σ_v/|v|; position as an
  Ornstein–Uhlenbeck wander of 0.3 m over 30 s; frames stamped with 0–0.3 ms jitter.

The truth (per-wheel μ, slip, loads, ρ_s, speed at 100 Hz) goes to ``independent_truth.csv``, which replay does
not read.
"""
import argparse
import datetime as dtm
import json
import math
import os
import numpy as np
import cantools

DBC = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "dbc" / "tractionecu.dbc")
G = 9.81
T0 = 1783670400.0  # 2026-07-10 08:00:00 UTC

SOILS = {  # mumax, s_c, rho_s, draft_nominal [N]
    "firm": (0.78, 0.11, 0.05, 20000.0),
    "soft": (0.58, 0.17, 0.10, 14000.0),
    "mud": (0.50, 0.20, 0.12, 30000.0),
}


def nmea(body):
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"${body}*{cs:02X}"


def fmt_lat(lat):
    h = "N" if lat >= 0 else "S"; lat = abs(lat); d = int(lat); m = (lat - d) * 60
    return f"{d:02d}{m:08.5f}", h


def fmt_lon(lon):
    h = "E" if lon >= 0 else "W"; lon = abs(lon); d = int(lon); m = (lon - d) * 60
    return f"{d:03d}{m:08.5f}", h


def run(cfg, out):
    rng = np.random.default_rng(cfg.get("seed", 0))
    os.makedirs(out, exist_ok=True)
    dt = 0.001
    T = cfg["duration"]
    n = int(round(T / dt))
    # vehicle truth
    m = 6300.0; L = 2.5; hcg = 1.0; hh = 0.5; db = 1.0; w = 1.8; f0 = 0.40
    beta = math.radians(cfg.get("pull_deg", 4.0))
    J = 60.0; rho_t = 0.015; r0 = 0.80; kz = 250e3; sigma_rel = 0.3
    front_roll = 0.3
    W = m * G
    Fref = W / 4
    # sensor errors
    tg = np.array(cfg.get("torque_gain", [1, 1, 1, 1]), float)
    to = np.array(cfg.get("torque_off", [0, 0, 0, 0]), float)
    axle_off = cfg.get("axle_off", 0.0); draft_off = cfg.get("draft_off", 0.0)
    wheel_rate = cfg.get("wheel_rate", 100.0); load_rate = cfg.get("load_rate", 50.0)
    eta_true = cfg.get("eta_true", 1.0)
    gps_lat = cfg.get("gps_latency", 0.0)
    # profile: list of segments (t_end, v_ref, curvature, soil, work)
    segs = cfg["segments"]
    mech = cfg.get("mech", False)
    Tref = 600.0; ig = 2.2; ifd = 28.0; itot = ig * ifd; Je = 2.0; lead = 0.03
    kf = (1 + lead) * (r0 - (W * (1 - f0) / 2 / kz) / 3) / (r0 - (W * f0 / 2 / kz) / 3)
    Te = 0.0
    next_eec = 0.0

    def seg_at(t):
        for s in segs:
            if t < s[0]:
                return s
        return segs[-1]

    # state
    x = y = 0.0; psi = math.radians(90.0)  # heading east (course 90)
    v = 0.0; om = np.zeros(4); F = np.zeros(4); I = 0.0
    dgm = 0.0; depth_phase = rng.uniform(0, 2 * math.pi)
    ylat = np.array([w / 2, -w / 2, w / 2, -w / 2])
    draft = 0.0; work_level = 0.0
    rec_every = 10  # 100 Hz truth
    tr = []
    can_events = []  # (t, msgname, dict)
    gps_rows = []
    db_ = cantools.database.load_file(DBC)
    next_wheel = 0.0; next_load = 0.0; next_wbsd = 0.0; next_gps = 0.1
    a_prev = 0.0
    vref_f = 0.0
    hist = []  # for gps latency (t, x, y, vE, vN)
    for k in range(n):
        t = k * dt
        s_end, vref, kap, soil, work = seg_at(t)
        mumax, sc, rho_s, D0 = SOILS[soil]
        # smooth reference
        vref_f += (vref - vref_f) * dt / 1.5
        # draft: implement in work when work flag; ramps
        work_level += ((1.0 if work else 0.0) - work_level) * dt / 1.5
        dgm += -dgm * dt / 2.0 + 0.08 * math.sqrt(2 * dt / 2.0) * rng.standard_normal()
        depth = 1.0 + 0.25 * math.sin(2 * math.pi * t / 40.0 + depth_phase)
        draft = work_level * D0 * depth * (1 + dgm) * (0.85 + 0.15 * abs(v) / 2.5)
        if v < 0:
            draft = 0.0
        # loads
        a = a_prev
        Fv = draft * math.tan(beta)
        Fzf = (W * f0 * L - draft * hh - m * a * hcg - Fv * db) / L
        Fzr = W + Fv - Fzf
        Mroll = m * v * v * kap * hcg
        dFf = front_roll * Mroll / w; dFr = (1 - front_roll) * Mroll / w
        # kap>0 left turn: right wheels (FR, RR) outer
        Fz = np.array([Fzf / 2 - dFf, Fzf / 2 + dFf, Fzr / 2 - dFr, Fzr / 2 + dFr])
        r = r0 - (Fz / kz) / 3.0
        # wheel ground speeds (Ackermann), rear axle ref
        fac = 1 - kap * ylat
        vg = v * np.array([math.sqrt(fac[0] ** 2 + (kap * L) ** 2), math.sqrt(fac[1] ** 2 + (kap * L) ** 2), fac[2], fac[3]])
        vw = om * r
        den = np.maximum(np.maximum(np.abs(vw), np.abs(vg)), 0.05)
        s = (vw - vg) / den  # signed: >0 driving forward
        mu_ss = mumax * (Fz / Fref) ** (-0.08) * np.tanh(s / sc)
        F += (np.maximum(np.abs(vg), np.abs(vw)) + 0.05) / sigma_rel * (mu_ss * Fz - F) * dt
        # controller (force demand)
        err = vref_f - v
        I += 0.4 * err * dt * m
        I = float(np.clip(I, -40e3, 40e3))
        Fcmd = m * 1.2 * err + I + (draft + rho_s * W) * np.sign(vref_f if abs(vref_f) > 1e-3 else 0.0)
        share = Fz / Fz.sum()
        Mmot = Fcmd * share * np.mean(r) / eta_true
        Mmot = np.clip(Mmot, -9000, 9000)
        # traction control: cut torque on a wheel slipping beyond 30 %
        if cfg.get('tcs', True):
            over = np.abs(vw) * 0.7 > np.maximum(np.abs(vg), 0.15)
            tcs = np.where(over, np.clip(1 - (np.abs(vw) * 0.7 - np.maximum(np.abs(vg), 0.15)) / 0.1, 0, 1), 1.0)
        else:  # motor speed limit only: wheel rim speed capped at spin_max m/s
            sm = cfg.get('spin_max', 3.0)
            tcs = np.clip(1 - (np.abs(vw) - sm) / 0.2, 0, 1)
        Mmot = Mmot * tcs
        Mw = np.where(Mmot >= 0, eta_true * Mmot, Mmot / eta_true)
        stop = (vref == 0.0 and abs(v) < 0.03 and abs(vref_f) < 0.03)
        if stop:
            Mmot[:] = 0.0; Mw[:] = 0.0; om[:] = 0.0; F[:] = 0.0; v = 0.0; I = 0.0; a = 0.0
        elif mech:
            Te = float(np.clip(Fcmd * np.mean(r) / (eta_true * itot), -40.0, 1.1 * Tref))
            sg = np.tanh(om / 0.05)
            res = r * (F + rho_t * Fz * sg)
            Jeq = 2 * J + 2 * J * kf ** 2 + Je * itot ** 2
            wr = om[2] + (eta_true * itot * Te - res[2:].sum() - kf * res[:2].sum()) / Jeq * dt
            om[:] = [kf * wr, kf * wr, wr, wr]
            cosd = np.array([math.cos(math.atan(kap * L))] * 2 + [1.0, 1.0])
            Fx = (F * cosd).sum() - draft - rho_s * W * math.tanh(v / 0.05) - 0.5 * 1.2 * 4.5 * v * abs(v)
            a = Fx / m
            v += a * dt
        else:
            sg = np.tanh(om / 0.05)
            om += (Mw - r * (F + rho_t * Fz * sg)) / J * dt
            cosd = np.array([math.cos(math.atan(kap * L))] * 2 + [1.0, 1.0])
            Fx = (F * cosd).sum() - draft - rho_s * W * math.tanh(v / 0.05) - 0.5 * 1.2 * 4.5 * v * abs(v)
            a = Fx / m
            v += a * dt
        a_prev = a
        psi += v * kap * dt
        x += v * math.cos(psi) * dt; y += v * math.sin(psi) * dt
        hist.append((t, x, y, v * math.cos(psi), v * math.sin(psi)))
        if len(hist) > 400:
            hist.pop(0)
        # sensors
        if mech and t >= next_eec - 1e-9:
            next_eec += 0.02
            can_events.append((t, "EEC1", {"EngineTorqueMode": 0, "DriversDemandEnginePercentTorque": round(Te / Tref * 100),
                                           "ActualEnginePercentTorque": float(np.clip(round(Te / Tref * 100 * cfg.get('torque_gain', [1])[0]), -125, 125)),
                                           "EngineSpeed": float(np.clip(itot * om[2], 0, 840)), "EngineDemandPercentTorque": round(Te / Tref * 100)}))
        if mech and t >= next_wbsd - 1e-9:
            rd = 0.777
            fa = abs(om[0]) * rd * (1 + 0.002 * rng.standard_normal()); ra = abs(om[2]) * rd * (1 + 0.002 * rng.standard_normal())
            vr = abs(v) * (1 + 0.01 * rng.standard_normal()) + 0.01 * rng.standard_normal()
            dirn = 1 if np.mean(om) >= 0 else 0
            can_events.append((t + 0.0001, "ETC2", {"TransmissionSelectedGear": 5, "TransmissionActualGearRatio": ig, "TransmissionCurrentGear": 5}))
            can_events.append((t + 0.0002, "CCVS1", {"ParkingBrakeSwitch": 0, "WheelBasedVehicleSpeed": ra}))
            rel = float(np.clip(ra - fa, -2.17, 2.17))
            can_events.append((t + 0.0003, "EBC2", {"FrontAxleSpeed": fa, "RelativeSpeedFrontAxleLeftWheel": 0.0, "RelativeSpeedFrontAxleRightWheel": 0.0,
                                                    "RelativeSpeedRearAxle1LeftWheel": rel, "RelativeSpeedRearAxle1RightWheel": rel,
                                                    "RelativeSpeedRearAxle2LeftWheel": 0.0, "RelativeSpeedRearAxle2RightWheel": 0.0}))
            can_events.append((t + 0.0004, "GBSD", {"GroundBasedMachineSpeed": max(vr, 0.0), "GroundBasedMachineDistance": 0.0, "GroundBasedMachineDirection": dirn}))
        if not mech and t >= next_wheel - 1e-9:
            next_wheel += 1.0 / wheel_rate
            omm = om * (1 + 0.002 * rng.standard_normal(4)) + 0.005 * rng.standard_normal(4)
            Mm = tg * Mmot * (1 + 0.01 * rng.standard_normal(4)) + to + 5 * rng.standard_normal(4)
            can_events.append((t, "TECU_WheelSpeeds", {f"WheelSpeed_{c}": float(np.clip(np.round(omm[i], 3), -32.767, 32.767)) for i, c in enumerate(["FL", "FR", "RL", "RR"])}))
            can_events.append((t + 0.0002, "TECU_DriveTorques", {f"DriveTorque_{c}": float(2 * np.round(Mm[i] / 2)) for i, c in enumerate(["FL", "FR", "RL", "RR"])}))
        if t >= next_load - 1e-9:
            next_load += 1.0 / load_rate
            fzm = max(0.0, Fzf * cfg.get("axle_gain", 1.0) + axle_off + 300 * rng.standard_normal())
            dm = draft + draft_off + 300 * rng.standard_normal()
            if not mech: can_events.append((t + 0.0004, "TECU_AxleLoad", {"FrontAxleLoad": float(5 * round(fzm / 5)), "FrontAxleLoadStatus": 0}))
            can_events.append((t + 0.0006, "RearHitchStatus", {"RearHitchPosition": 20.0 if work else 80.0, "RearHitchInWorkIndication": 1 if work else 0,
                                                                "RearNominalLowerLinkForce": 0.0, "DraftForce": float(10 * round(dm / 10))}))
        if t >= next_wbsd - 1e-9:
            next_wbsd += 0.1
            vwb = abs(np.mean(om[2:]) * 0.775)
            can_events.append((t + 0.0008, "WBSD", {"WheelBasedMachineSpeed": round(min(vwb, 64.0), 3), "WheelBasedMachineDistance": 0.0,
                                                     "WheelBasedMachineDirection": 1 if np.mean(om) >= 0 else 0}))
        if t >= next_gps - 1e-9:
            next_gps += 0.1
            tg_ = t - gps_lat
            hh_ = min(hist, key=lambda h: abs(h[0] - tg_))
            gps_rows.append((t, hh_[1], hh_[2], hh_[3], hh_[4]))
        if k % rec_every == 0:
            mu = F / Fz
            tr.append([t + T0, *mu, rho_s, *s, v, *Fz, draft, Fzf, kap, 1 if work else 0, *Mw, *om, soil == "firm"])
    # truth
    cols = ["t", "mu_FL", "mu_FR", "mu_RL", "mu_RR", "rho_s", "slip_FL", "slip_FR", "slip_RL", "slip_RR", "v",
            "fz_FL", "fz_FR", "fz_RL", "fz_RR", "fdx", "fzf", "curvature", "work", "Mw_FL", "Mw_FR", "Mw_RL", "Mw_RR",
            "om_FL", "om_FR", "om_RL", "om_RR", "soil_firm"]
    np.savetxt(os.path.join(out, "independent_truth.csv"), np.array(tr), delimiter=",", header=",".join(cols), comments="", fmt="%.6f")
    # CAN
    jit = cfg.get("jitter", "normal")
    lines = []
    for (t, name, sig) in can_events:
        msg = db_.get_message_by_name(name)
        data = msg.encode(sig, strict=False)
        fid = msg.frame_id & 0x1FFFFFFF
        if jit == "normal":
            ts = t + rng.uniform(0, 0.0003)
        elif jit == "usb":  # frames delivered in 8 ms USB batches, stamped on arrival + host jitter
            ts = math.ceil((t + 1e-6) / 0.008) * 0.008 + abs(rng.normal(0, 0.002))
        elif jit == "large":
            ts = t + rng.normal(0, 0.005)
        lines.append((ts, f"can0 {fid:08X}#{data.hex().upper()}"))
    if cfg.get("sort_ts", True):
        lines.sort(key=lambda z: z[0])
    with open(os.path.join(out, "can.log"), "w") as f:
        for ts, l in lines:
            f.write(f"({T0 + ts:.6f}) {l}\n")
    # GNSS
    lat0, lon0 = 47.8816, -110.5534
    Rm = 6371000.0
    pe = pn = 0.0
    gl = []
    for (t, xx, yy, vE, vN) in gps_rows:
        pe += -pe * 0.1 / 30 + 0.3 * math.sqrt(2 * 0.1 / 30) * rng.standard_normal()
        pn += -pn * 0.1 / 30 + 0.3 * math.sqrt(2 * 0.1 / 30) * rng.standard_normal()
        lat = lat0 + math.degrees((yy + pn) / Rm)
        lon = lon0 + math.degrees((xx + pe) / (Rm * math.cos(math.radians(lat0))))
        ve = vE + 0.05 * rng.standard_normal(); vn = vN + 0.05 * rng.standard_normal()
        sog = math.hypot(ve, vn); cog = (math.degrees(math.atan2(ve, vn)) + 360) % 360
        if cfg.get("cog_exact"):
            cog = (math.degrees(math.atan2(vE, vN)) + 360) % 360
        elif cfg.get("cog_sigma_deg") is not None:
            cog = (math.degrees(math.atan2(vE, vN)) + cfg["cog_sigma_deg"] * rng.standard_normal() + 360) % 360
        ut = T0 + round(t, 1)
        d = dtm.datetime.fromtimestamp(ut, dtm.timezone.utc)
        hms = d.strftime("%H%M%S") + f".{int(round(d.microsecond / 1e4)):02d}"
        dmy = d.strftime("%d%m%y")
        la, lh = fmt_lat(lat); lo, loh = fmt_lon(lon)
        kn = sog / 0.514444
        gl.append(nmea(f"GNGGA,{hms},{la},{lh},{lo},{loh},2,16,0.90,862.0,M,0.0,M,,"))
        gl.append(nmea(f"GNRMC,{hms},A,{la},{lh},{lo},{loh},{kn:.3f},{cog:.2f},{dmy},,,D,V"))
        gl.append(nmea(f"GNVTG,{cog:.2f},T,,M,{kn:.3f},N,{sog * 3.6:.3f},K,D"))
    with open(os.path.join(out, "gps.nmea"), "w") as f:
        f.write("\r\n".join(gl) + "\r\n")
    # vehicle.toml
    vt = MECH_TOML if cfg.get("mech") else VEHICLE_TOML
    with open(os.path.join(out, "vehicle.toml"), "w") as f:
        f.write(vt.format(pull=cfg.get("pull_decl", 4.0), wheel_rate=wheel_rate, loadpin_rate=load_rate,
                          eta=cfg.get("eta_decl", 1.0), eta_tol=cfg.get("eta_tol", 0.0)))
    json.dump(cfg, open(os.path.join(out, "cfg.json"), "w"), indent=1)
    return {"frames": len(lines), "epochs": len(gps_rows)}


_VEHICLE_TABLE = """[vehicle]
mass_kg = 6300.0
wheel_mass_kg = 160.0
r0_m = 0.8
tyre_width_m = 0.54
tyre_pressure_pa = 160000.0
wheel_inertia_kgm2 = 60.0
rho_t = 0.015
wheelbase_m = 2.5
cg_height_m = 1.0
hitch_height_m = 0.5
static_front_fraction = 0.4
track_width_m = 1.8
pull_angle_deg = {pull}
pull_angle_tol_deg = 2.0
"""
"""The machine both drive lines share (the truth's own figures, :func:`run`)."""

VEHICLE_TOML = _VEHICLE_TABLE + """rated_power_w = 80000.0
front_roll_share = 0.3

[vehicle.drivetrain]
kind = "hub"
efficiency = {eta}
efficiency_tolerance = {eta_tol}
rolling_radius_m = 0.777
load_sensing = "front-axle"
draft_sensing = true

[sensors]
wheel_rate_hz = {wheel_rate}
loadpin_rate_hz = {loadpin_rate}
"""

MECH_TOML = _VEHICLE_TABLE + """
[vehicle.drivetrain]
kind = "mechanical"
final_drive_ratio = 28.0
gear_ratio = "bus"
efficiency = 0.9
efficiency_tolerance = 0.03
front_drive = "engaged"
front_lead = 0.03
engine_reference_torque_nm = 600.0
engine_inertia_kgm2 = 2.0
wheel_speeds = "per-axle"
wheel_speed_radius_m = 0.777
rolling_radius_m = 0.777
load_sensing = "none"
draft_sensing = true
"""

SCEN = {
    # straight two soils: firm then soft, 160 s
    "straight2": dict(duration=160, segments=[(8, 2.5, 0.0, "firm", False), (80, 2.5, 0.0, "firm", True), (160, 2.5, 0.0, "soft", True)]),
    "curve30": dict(duration=120, segments=[(8, 2.2, 0.0, "firm", False), (60, 2.2, 1 / 30, "firm", True), (120, 2.2, -1 / 30, "soft", True)]),
    "reverse": dict(duration=100, segments=[(8, 2.0, 0.0, "firm", False), (40, 2.0, 0.0, "firm", True), (48, 0.0, 0.0, "firm", False),
                                            (70, -1.0, 0.0, "firm", False), (76, 0.0, 0.0, "firm", False), (100, 2.0, 0.0, "firm", True)]),
    "stuck": dict(duration=60, segments=[(8, 2.0, 0.0, "firm", False), (30, 2.0, 0.0, "firm", True), (60, 2.0, 0.0, "mud", True)]),
    "mech2": dict(duration=160, mech=True, load_rate=10.0, eta_true=0.9,
                  segments=[(8, 2.5, 0.0, "firm", False), (80, 2.5, 0.0, "firm", True), (160, 2.5, 0.0, "soft", True)]),
    "stops": dict(duration=120, segments=[(8, 2.5, 0.0, "firm", False), (40, 2.5, 0.0, "firm", True), (55, 0.0, 0.0, "firm", True),
                                          (85, 2.5, 0.0, "soft", True), (100, 0.0, 0.0, "soft", True), (120, 2.5, 0.0, "soft", True)]),
}


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario"); ap.add_argument("out"); ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    cfg = dict(SCEN[a.scenario])
    for kv in a.set:
        k, v = kv.split("=", 1)
        cfg[k] = json.loads(v)
    run(cfg, a.out)
