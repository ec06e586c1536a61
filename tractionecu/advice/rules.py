"""Recommendations for the driver, each with the numbers it rests on.  The service never acts on the machine.

Two triggers (issue: "what farmers act on today"):

1. **Slip outside the band** of the axle type over a distance: the
   distance-weighted mean of the machine's operating slip over the last
   ``distance_m`` metres of pulling lies outside the band.  Operator-manual
   bands: MFWD 8–12 %, two-wheel drive 10–15 %, tracks 2–5 % (ASABE EP496
   gives the same ranges by soil: 8–10 % firm, 11–13 % tilled, 13–15 % soft).
   Slip *above* the band fires (too little weight on the wheels: wear,
   soil smearing, lost pull), unless the identified curve puts the optimum
   s* above it (its interval's lower end above the slip): the measured curve
   outranks the rule of thumb.  Slip *below* it fires only when the
   identified curve says that running nearer s* would gain at least
   ``eta_loss`` of efficiency over that distance: a tractor at a light load
   runs below the band with nothing to gain from less ballast, and advice
   the driver learns to ignore is worse than none.
2. **η far below η(s*)** for minutes: the mean of η* − η over the last
   ``eta_minutes`` minutes (while s* and η are valid) exceeds ``eta_loss``.

Advice given stays until its trigger is well off (:data:`HOLD_BAND_SHARE`, :data:`HOLD_LOSS_SHARE`).

Each trigger gives recommendations by the side of the optimum it is on.  The amounts use the pull P
averaged over the window (not the instant's), and advice whose window has held no pulling for
:data:`EXPIRY_S` is withdrawn.

* slip too high (s > s*): **add ballast**.  The pull P = Σ (μ_i − ρ_s) F_z,i
  stays; at the target slip s_t (s*, else the band's middle) each newton of
  weight gives μ(s_t) − ρ_s of pull, so W' = P/(μ(s_t) − ρ_s) and the
  ballast is (W' − W)/g, W the weight on the driven wheels (a two-wheel
  drive's rear axle with the pull's load transfer, its ballast on the rear).  Where: towards the axle type's static front share
  (:data:`FRONT_SHARE`; the axles' slips do not say it: an MFWD front axle's
  lead makes its slip the larger one whatever the weights), then the tyre
  pressures of the tyre's load table for the new axle loads.  At most up to
  the machine's permissible mass (``max_mass_kg``, where declared) and the
  permissible axle loads (``max_front_axle_kg``, ``max_rear_axle_kg``: the
  static axle loads with the ballast stay within them; an axle at its limit
  passes its share to the other while that one has room): the advice says
  how much more the pull needs, and at the limits it gives no ballast at
  all, only the alternatives, saying why.  Or, without
  ballast, **lower the tyre pressure** if the tyre profile allows it at the
  present load (``tyre_pressure_min_pa`` > 0): a longer contact patch raises
  the pull at a given slip.  Or a **shallower working depth**: the draft to
  shed is P − (μ(s_t) − ρ_s)·W.  (A lower gear at the same pull leaves the
  slip where it is.)
* slip too low (s < s*): **remove ballast**, at most the ballast declared
  carried (``ballast_kg``; undeclared: no amount, only the weight the pull
  needs, W' = P/(μ(s*) − ρ_s), against the machine's), or **pull more** with
  the same weight (a wider or deeper implement: (μ(s*) − ρ_s)·W − P more
  draft).  A tractor at a light pull is underloaded: taking off weight below
  its bare mass is no advice.

The amounts are first estimates from the identified curve: they say what
the curve implies, not what the next field will do.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

from .efficiency import G, CurveParams, EfficiencyReport

SLIP_BANDS: dict[str, tuple[float, float]] = {
    "mfwd": (0.08, 0.12),
    "4wd": (0.08, 0.12),
    "2wd": (0.10, 0.15),
    "tracks": (0.02, 0.05),
}
"""Slip bands for ballasting by axle type [-] (operator manuals; ASABE EP496)."""

FRONT_SHARE: dict[str, tuple[float, float]] = {
    "mfwd": (0.35, 0.40),
    "4wd": (0.55, 0.60),
}
"""Static share of the weight on the front axle to ballast towards, by axle type [-] (Zoz & Grisso 2003,
"Traction and tractor performance", ASAE; Grisso et al., Virginia Cooperative Extension 442-450: MFWD
35/65, 4WD 55/45 to 60/40).  Where ballast goes follows the static split, not the axles' slips: on an MFWD
tractor the front axle's lead makes its slip the larger one whatever the weights.  A two-wheel drive's
traction ballast goes on its driven rear axle (its 25–30 % front is for steering, not for pull); tracks
are ballasted as a whole."""

HOLD_BAND_SHARE = 0.25
"""Hysteresis of the slip band: advice given for a slip above the band stays until the window's slip is back
below the band's upper end by this share of the band's width (an MFWD's 12 % less 1 %: 11 %), one for a slip
below it until the slip is above the lower end by as much [-].  Without it a window's mean slip wandering about
12 % gave and withdrew "add ballast, about 1000 kg" five times in ten minutes, once for 6.7 s."""

HOLD_LOSS_SHARE = 0.8
"""... and advice given for an efficiency loss stays while the loss is above this share of ``eta_loss`` [-]."""

EXPIRY_S = 60.0
"""Advice whose window holds no pulling for this long [s] is withdrawn (the field, or its end, is left: road
transport, a long stop)."""


@dataclass(frozen=True)
class AdviceSettings:
    """Thresholds of the advice (the service's ``[advice]``)."""

    axle_type: str = "mfwd"
    slip_min: float = math.nan
    """Lower end of the band [-]; NaN: the axle type's."""
    slip_max: float = math.nan
    """Upper end of the band [-]; NaN: the axle type's."""
    distance_m: float = 100.0
    """Slip must stay outside the band over this distance of pulling [m]."""
    eta_loss: float = 0.05
    """η* − η above this is "far below the optimum" [-]."""
    eta_minutes: float = 2.0
    """... for this long [min]."""
    tyre_pressure_pa: float = math.nan
    """Tyre pressure now [Pa] (the vehicle's)."""
    tyre_pressure_min_pa: float = 0.0
    """Lowest tyre pressure the tyre's load table allows [Pa]; 0: lowering is not advised."""
    tyre_pressure_step_pa: float = 20e3
    """Pressure step of a recommendation [Pa]."""
    ballast_kg: float = math.nan
    """Ballast the machine carries now [kg] (front weights, wheel weights, liquid); NaN: not declared, and then
    no amount of ballast to remove is given (only what the pull needs against what the machine weighs)."""
    max_mass_kg: float = math.nan
    """The machine's permissible total mass [kg] (its registration document or operator's manual: tyres,
    axles and brakes are rated for it); NaN: not declared, and then the ballast advised is not limited."""
    max_front_axle_kg: float = math.nan
    """Permissible load of the front axle [kg] (registration document, operator's manual); NaN: not declared."""
    max_rear_axle_kg: float = math.nan
    """Permissible load of the rear axle [kg]; NaN: not declared."""

    def band(self) -> tuple[float, float]:
        lo, hi = SLIP_BANDS[self.axle_type]
        return (lo if math.isnan(self.slip_min) else self.slip_min, hi if math.isnan(self.slip_max) else self.slip_max)


@dataclass
class Recommendation:
    """One piece of advice: ``kind`` (``add_ballast``, ``remove_ballast``, ``lower_tyre_pressure``,
    ``shallower_depth``, ``higher_gear``), a sentence, and the numbers it rests on."""

    kind: str
    text: str
    trigger: str
    evidence: dict[str, float | str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        ev = {k: (round(v, 5) if isinstance(v, float) and math.isfinite(v) else (None if isinstance(v, float) else v))
              for k, v in self.evidence.items()}
        return {"kind": self.kind, "text": self.text, "trigger": self.trigger, "evidence": ev}


class Advisor:
    """Turns a stream of :class:`EfficiencyReport` (about 10 Hz) into recommendations (module doc)."""

    def __init__(self, settings: AdviceSettings | None = None, *, weight_n: float = 6300 * G,
                 front_fraction: float = 0.4, wheelbase_m: float = 2.5, hitch_height_m: float = 0.5,
                 wheel_power_w: float = math.nan) -> None:
        self.s = self.declared = settings or AdviceSettings()
        # an MFWD whose front drive is off is advised as a two-wheel drive (:meth:`update`)
        self._front_off = (replace(self.declared, axle_type="2wd") if self.declared.axle_type == "mfwd"
                           else self.declared)
        if self.s.axle_type not in SLIP_BANDS:
            raise ValueError(f"axle type {self.s.axle_type!r}: not one of {', '.join(SLIP_BANDS)}")
        self.weight_n = weight_n
        self.front_fraction = front_fraction
        self.L = wheelbase_m
        self.h = hitch_height_m
        self.wheel_power_w = wheel_power_w
        """Most power the drivetrain puts on the wheels [W]: the rated power times the drivetrain's efficiency
        (the vehicle's); NaN: not known, the draft advised is not bounded by it."""
        self._v = math.nan                          # ground speed of the last pulling report [m/s]
        # (d, slip, loss or nan, s − s*, t, pull or nan)
        self._dist: deque[tuple[float, float, float, float, float, float]] = deque()
        # Σd, Σd·slip, Σd (loss known), Σd·loss, Σd·(s − s*), Σd (pull known), Σd·pull over the window
        self._sums = [0.0] * 7
        self._n_added = 0
        # (t, s*, curve) of the last identified s*
        self._s_star_seen: tuple[float, float, CurveParams | None] | None = None
        self._eta: deque[tuple[float, float]] = deque()
        self._eta_sum = 0.0
        self._t: float | None = None
        self.active: list[Recommendation] = []
        self.last_report: EfficiencyReport | None = None

    def update(self, rep: EfficiencyReport, v: float, curve: CurveParams | None,
               slip_axles: tuple[float, float] = (math.nan, math.nan), front_driven: bool = True
               ) -> list[Recommendation]:
        """Add one report (ground speed ``v`` [m/s], the identified ``curve``, front and rear slip); the advice now.

        ``front_driven`` False (an MFWD's front drive disengaged, as the machine-level estimator finds it): the
        tractor pulls as a two-wheel drive, and is advised as one (its slip band, the rear axle's weight, the
        ballast on the rear axle) while it does."""
        self.s = self.declared if front_driven else self._front_off
        t = rep.t
        dt = 0.0 if self._t is None or not math.isfinite(t) else min(max(t - self._t, 0.0), 1.0)
        self._t = t
        self.last_report = rep
        if rep.s_star_valid and math.isfinite(rep.s_star):
            self._s_star_seen = (t, rep.s_star, curve)
        if self._dist and math.isfinite(t) and t - self._dist[-1][4] > EXPIRY_S:
            # nothing pulled for a minute: the window (and the advice it gave) is about ground left behind; so
            # are the minutes of η (kept, they spanned the stop and gave the η advice a few seconds after it)
            self._dist.clear()
            self._sums = [0.0] * 7
            self._eta.clear()
            self._eta_sum = 0.0
        if rep.slip_ok and math.isfinite(v):
            self._v = abs(v)
            dd = abs(v) * dt
            loss = rep.eta_lost if rep.s_star_valid else math.nan
            side = rep.slip - rep.s_star if rep.s_star_valid else math.nan
            item = (dd, rep.slip, loss, side, t, rep.pull_n)
            self._dist.append(item)
            self._add(item, 1.0)
            while self._dist and self._sums[0] - self._dist[0][0] >= self.s.distance_m:
                self._add(self._dist.popleft(), -1.0)
            self._n_added += 1
            if self._n_added % 4096 == 0:        # running sums: recompute now and then (rounding)
                self._sums = [0.0] * 7
                for x in self._dist:
                    self._add(x, 1.0)
        if rep.s_star_valid and rep.eta_valid:
            self._eta.append((t, rep.eta_lost))
            self._eta_sum += rep.eta_lost
        horizon = self.s.eta_minutes * 60.0
        while self._eta and t - self._eta[0][0] > horizon:
            self._eta_sum -= self._eta.popleft()[1]
        self.active = self._decide(rep, curve, slip_axles)
        return self.active

    # ------------------------------------------------------------ triggers
    def _add(self, x: tuple[float, float, float, float, float, float], sign: float) -> None:
        d, slip, loss, side, _, pull = x
        s = self._sums
        s[0] += sign * d
        s[1] += sign * d * slip
        if math.isfinite(loss):
            s[2] += sign * d
            s[3] += sign * d * loss
            s[4] += sign * d * side
        if math.isfinite(pull):
            s[5] += sign * d
            s[6] += sign * d * pull

    def window_pull(self) -> float:
        """Distance-weighted mean pull over the window [N] (the amounts rest on it, not on the instant's pull:
        from the instant's the ballast figure moved 1.1–2.3 t within a minute on one soil); NaN when unknown."""
        return self._sums[6] / self._sums[5] if self._sums[5] > 0.5 * self._sums[0] > 0 else math.nan

    def _window_means(self) -> tuple[float, float, float, float]:
        """Distance-weighted mean slip, η loss and (s − s*) over the window, and the window's length [m]."""
        d, dslip, dl, dloss, dside = self._sums[:5]
        if d <= 1e-9:
            return math.nan, math.nan, math.nan, 0.0
        slip = dslip / d
        loss = dloss / dl if dl > 0.5 * d else math.nan
        side = dside / dl if dl > 0.5 * d else math.nan
        return slip, loss, side, d

    def _decide(self, rep: EfficiencyReport, curve: CurveParams | None,
                slip_axles: tuple[float, float]) -> list[Recommendation]:
        lo, hi = self.s.band()
        slip, loss, side, d = self._window_means()
        out: list[Recommendation] = []
        ev_base: dict[str, float | str] = {"band_lo": lo, "band_hi": hi, "axle_type": self.s.axle_type}
        # hysteresis (HOLD_BAND_SHARE, HOLD_LOSS_SHARE): advice given stays until the slip is back well inside
        was_high = any(r.kind == "add_ballast" for r in self.active)
        was_low = any(r.kind == "remove_ballast" for r in self.active)
        m = HOLD_BAND_SHARE * (hi - lo)
        hi_off, lo_off = (hi - m if was_high else hi), (lo + m if was_low else lo)
        loss_on = self.s.eta_loss * (HOLD_LOSS_SHARE if was_low else 1.0)
        if d >= self.s.distance_m * 0.999 and math.isfinite(slip):
            ev = {**ev_base, "mean_slip": slip, "distance_m": d, "eta_loss_mean": loss}
            if slip > hi_off and not (rep.s_star_valid and slip < rep.s_star_lo):
                # (above the band but below the identified optimum: the curve says more slip pays here)
                why = (f"slip {slip:.1%} above the {lo:.0%}–{hi:.0%} band over {d:.0f} m" if slip > hi else
                       f"slip {slip:.1%} over {d:.0f} m, not yet back below {hi_off:.0%} since it rose above the "
                       f"{lo:.0%}–{hi:.0%} band")
                out += self._too_high(rep, curve, why, ev, slip_axles, (lo, hi))
            elif slip < lo_off and math.isfinite(loss) and loss >= loss_on:
                why = (f"slip {slip:.1%} below the {lo:.0%}–{hi:.0%} band over {d:.0f} m" if slip < lo else
                       f"slip {slip:.1%} over {d:.0f} m, not yet back above {lo_off:.0%} since it fell below the "
                       f"{lo:.0%}–{hi:.0%} band")
                out += self._too_low(rep, curve, f"{why}, {loss:.3f} of efficiency lost", ev)
        if not out and self._eta:
            span = self._eta[-1][0] - self._eta[0][0]
            mean_loss = self._eta_sum / len(self._eta)
            eta_on = self.s.eta_loss * (HOLD_LOSS_SHARE if was_high or was_low else 1.0)
            if span >= 0.95 * self.s.eta_minutes * 60.0 and mean_loss >= eta_on and math.isfinite(side):
                ev = {**ev_base, "eta_loss_mean": mean_loss, "minutes": span / 60.0, "mean_slip": slip,
                      "mean_slip_minus_s_star": side}
                why = f"η {mean_loss:.3f} below η(s*) for {span / 60:.1f} min"
                if side > 0:
                    out += self._too_high(rep, curve, why, ev, slip_axles, (lo, hi))
                else:
                    out += self._too_low(rep, curve, why, ev)
        return out

    # ------------------------------------------------------------ recommendations
    def _target(self, rep: EfficiencyReport, band: tuple[float, float]) -> tuple[float, str]:
        """The slip the ballast is sized for: s* inside the band (the band's nearer end for an s* outside it), the
        last identified s* for up to :data:`EXPIRY_S` while the present one is not, else the band's middle.
        Switching each second between s* (0.074, below an MFWD's band) and the band's middle moved the amount
        advised between 2885 and 1477 kg within 1.5 s."""
        lo, hi = band
        seen = self._s_star_seen                     # kept by update() from every report
        if seen is not None and rep.t - seen[0] <= EXPIRY_S:
            return min(max(seen[1], lo), hi), ("s*" if lo <= seen[1] <= hi else "s* brought into the band")
        return 0.5 * (lo + hi), "band middle"

    def _sizing_curve(self, rep: EfficiencyReport, curve: CurveParams | None) -> CurveParams | None:
        """The curve μ(s_t) is read on: the one the target s* was identified on while :meth:`_target` holds that
        s*, else the present one.  Sized on the present curve with the s* of another, the amount went from 1181
        to 4098 kg within 0.3 s on ``ballast-needed`` when the estimator's curve became a fit whose parameters
        it reported as unknown (σ(p) = 161) and s* no longer identified."""
        seen = self._s_star_seen
        if seen is not None and seen[2] is not None and rep.t - seen[0] <= EXPIRY_S:
            return seen[2]
        return curve

    def _weight_for(self, rep: EfficiencyReport, curve: CurveParams | None, s_t: float, pull: float) -> float:
        """W' = P/(μ(s_t) − ρ_s) [N] (module doc), P = ``pull`` the window's mean pull; NaN without a curve."""
        if curve is None or not (math.isfinite(pull) and math.isfinite(rep.rho_s)):
            return math.nan
        k = float(curve.mu(s_t)) - rep.rho_s
        return pull / k if k > 0.02 else math.nan

    def _driven_weight(self, pull: float) -> float:
        """The weight on the driven wheels [N]: the machine's, or on a two-wheel drive the rear axle's with the
        pull's load transfer, W (1 − f) + P h/L (the whole weight made 454 kg of a ballast the rear axle's
        balance puts near 1.9 t)."""
        if self.s.axle_type != "2wd":
            return self.weight_n
        return self.weight_n * (1.0 - self.front_fraction) + (pull * self.h / self.L if math.isfinite(pull) else 0.0)

    def _where(self, ballast_kg: float = math.nan) -> tuple[str, str, float]:
        """The axle to ballast, towards the axle type's static front share (:data:`FRONT_SHARE`): (``front``,
        ``rear`` or ``front and rear``; the words of the advice; the kilograms of ``ballast_kg`` on the front).

        A front share outside the range is brought to its nearer end, not past it: of the amount, x on the
        front with (f m + x)/(m + B) at that end, m the machine's mass, the rest on the rear.  All of 2328 kg on
        the rear of a 4.3 t MFWD tractor at 42 % front had left 27 % on the front, against 35 %–40 %."""
        if self.s.axle_type == "2wd":
            return "rear", "on the rear axle (the driven one)", 0.0
        lo_hi = FRONT_SHARE.get(self.s.axle_type)
        ff = self.front_fraction
        if lo_hi is None or not math.isfinite(ff):
            return "front and rear", "on both axles", math.nan
        lo, hi = lo_hi
        if lo <= ff <= hi:
            return ("front and rear", f"on both axles, keeping {lo:.0%}–{hi:.0%} of the weight on the front",
                    ff * ballast_kg)
        end = lo if ff < lo else hi
        if not (math.isfinite(ballast_kg) and ballast_kg > 0):
            return ("front", "on the front axle", math.nan) if ff < lo else ("rear", "on the rear axle", math.nan)
        m = self.weight_n / G
        x = min(max(end * (m + ballast_kg) - ff * m, 0.0), ballast_kg)
        if x >= ballast_kg - 0.5:
            return "front", "on the front axle", ballast_kg
        if x <= 0.5:
            return "rear", "on the rear axle", 0.0
        return ("front and rear", f"{x:.0f} kg of it on the front axle and {ballast_kg - x:.0f} kg on the rear, for "
                                  f"{end:.0%} of the weight on the front", x)

    def _axle_limits(self, ballast_kg: float, front_kg: float) -> tuple[float, float] | None:
        """(front, rear) kilograms of ``ballast_kg`` within the permissible axle loads, or None when the split
        ``front_kg`` already keeps both static axle loads within them (or neither limit is declared, or the split
        is not known).  An axle at its limit passes its share to the other while that one has room; what neither
        takes is left off."""
        lim_f, lim_r = self.s.max_front_axle_kg, self.s.max_rear_axle_kg
        if not (math.isfinite(ballast_kg) and ballast_kg > 0) or (math.isnan(lim_f) and math.isnan(lim_r)):
            return None
        m = self.weight_n / G
        ff = self.front_fraction
        if not (math.isfinite(front_kg) and math.isfinite(ff)):
            return None
        room_f = max(lim_f - ff * m, 0.0) if math.isfinite(lim_f) else math.inf
        room_r = max(lim_r - (1.0 - ff) * m, 0.0) if math.isfinite(lim_r) else math.inf
        f, r = front_kg, ballast_kg - front_kg
        if f <= room_f + 0.5 and r <= room_r + 0.5:
            return None
        if self.s.axle_type == "2wd":          # traction ballast on the driven rear axle only
            return 0.0, min(ballast_kg, room_r)
        if f > room_f:
            r, f = r + (f - room_f), room_f
        if r > room_r:
            f, r = min(f + (r - room_r), room_f), room_r
        return f, r

    def _limits_text(self) -> str:
        """The declared limits, in words: "the permissible mass of 9000 kg and the permissible axle loads (front
        4000 kg, rear not declared)"."""
        parts = []
        if math.isfinite(self.s.max_mass_kg):
            parts.append(f"the permissible mass of {self.s.max_mass_kg:.0f} kg")
        if math.isfinite(self.s.max_front_axle_kg) or math.isfinite(self.s.max_rear_axle_kg):
            parts.append(self._axle_text())
        return " and ".join(parts)

    def _axle_text(self) -> str:
        """The permissible axle loads in words: "the permissible axle loads (front 4000 kg, rear not declared)"."""
        lf, lr = self.s.max_front_axle_kg, self.s.max_rear_axle_kg
        return ("the permissible axle loads (front " + (f"{lf:.0f} kg" if math.isfinite(lf) else "not declared")
                + ", rear " + (f"{lr:.0f} kg" if math.isfinite(lr) else "not declared") + ")")

    def _too_high(self, rep: EfficiencyReport, curve: CurveParams | None, why: str, ev: dict[str, float | str],
                  slip_axles: tuple[float, float], band: tuple[float, float]) -> list[Recommendation]:
        s_t, target = self._target(rep, band)
        curve = self._sizing_curve(rep, curve)
        pull = self.window_pull()
        w_new = self._weight_for(rep, curve, s_t, pull)
        w_driven = self._driven_weight(pull)
        ballast_kg = need_kg = (w_new - w_driven) / G if math.isfinite(w_new) else math.nan
        # the permissible mass caps the ballast: what the pull needs beyond it cannot be loaded on
        room_kg = self.s.max_mass_kg - self.weight_n / G
        capped = math.isfinite(room_kg) and math.isfinite(need_kg) and need_kg > room_kg
        if capped:
            ballast_kg = max(room_kg, 0.0)
        transfer = pull * self.h / self.L if math.isfinite(pull) else math.nan
        sf, sr = slip_axles
        where, words, front_kg = self._where(ballast_kg)
        axle = self._axle_limits(ballast_kg, front_kg)
        if axle is not None:              # placed (and perhaps cut) by the permissible axle loads
            front_kg, rear_kg = axle
            capped = capped or front_kg + rear_kg < ballast_kg - 0.5
            ballast_kg = front_kg + rear_kg
            if front_kg >= 0.5 and rear_kg >= 0.5:
                where = "front and rear"
                words = f"{front_kg:.0f} kg of it on the front axle and {rear_kg:.0f} kg on the rear"
            else:
                where = "front" if front_kg >= 0.5 else "rear"
                words = f"on the {where} axle"
            if not capped:                # (a cut amount names the limits already)
                words += ", within " + self._axle_text()
        e = {**ev, "target_slip": s_t, "target": target, "pull_n": pull, "rho_s": rep.rho_s, "a": rep.a,
             "mu_at_target": float(curve.mu(s_t)) if curve is not None else math.nan,
             "weight_n": self.weight_n, "weight_driven_n": w_driven, "weight_needed_n": w_new, "load_transfer_n": transfer,
             "slip_front": sf, "slip_rear": sr, "front_share": self.front_fraction}
        if capped:                        # what the pull needs, and the limits declared
            e["ballast_needed_kg"] = need_kg
            e.update({k: v for k, v in (("max_mass_kg", self.s.max_mass_kg), ("max_front_axle_kg",
                      self.s.max_front_axle_kg), ("max_rear_axle_kg", self.s.max_rear_axle_kg)) if math.isfinite(v)})
        amount = (f"about {ballast_kg:.0f} kg" if math.isfinite(ballast_kg) and ballast_kg > 0
                  else "amount not estimated" + (" (curve not identified)" if curve is None else ""))
        limit = (f" (limited by {self._limits_text()}; this pull needs about {need_kg:.0f} kg)" if capped else "")
        p, pmin = self.s.tyre_pressure_pa, self.s.tyre_pressure_min_pa
        after = ("; then set the tyre pressures the tyre's load table gives for the new axle loads"
                 if pmin > 0 else "")
        recs: list[Recommendation] = []
        if not capped or ballast_kg >= 0.5:
            recs.append(Recommendation("add_ballast", f"Add ballast, {amount}{limit}, {words}{after}: {why}.", why,
                                       {**e, "ballast_kg": ballast_kg, "where": where, "ballast_front_kg": front_kg,
                                        "ballast_rear_kg": ballast_kg - front_kg}))
        full = ("" if recs else f" (no ballast can be added within {self._limits_text()}; this pull needs about "
                                f"{need_kg:.0f} kg more)")
        if pmin > 0 and math.isfinite(p) and p - self.s.tyre_pressure_step_pa >= pmin:
            # an alternative to the ballast, at the present loads (more load needs more pressure, not less)
            p_new = max(pmin, p - self.s.tyre_pressure_step_pa)
            lead = "Or, without adding ballast, lower" if recs else "Lower"
            recs.append(Recommendation("lower_tyre_pressure",
                                       f"{lead} the tyre pressure from {p / 1e5:.2f} to "
                                       f"{p_new / 1e5:.2f} bar (the tyre's minimum for the present load "
                                       f"{pmin / 1e5:.2f} bar){'' if recs else full}: {why}.", why,
                                       {**e, "tyre_pressure_pa": p, "tyre_pressure_new_pa": p_new,
                                        "tyre_pressure_min_pa": pmin}))
        shed = (pull - (float(curve.mu(s_t)) - rep.rho_s) * w_driven) if curve is not None else math.nan
        # (a lower gear at the same pull leaves the slip where it is: only less draft or more weight moves it)
        txt = (f"or work shallower: shed about {shed / 1e3:.1f} kN of draft"
               if math.isfinite(shed) and shed > 0 else "or work shallower")
        if not recs:                      # the first recommendation: it says why there is no ballast
            txt = txt[3:] + full
        recs.append(Recommendation("shallower_depth", txt[0].upper() + txt[1:] + f": {why}.", why,
                                   {**e, "draft_to_shed_n": shed}))
        return recs

    def _too_low(self, rep: EfficiencyReport, curve: CurveParams | None, why: str,
                 ev: dict[str, float | str]) -> list[Recommendation]:
        s_t = rep.s_star
        pull = self.window_pull()
        w_new = self._weight_for(rep, curve, s_t, pull)
        w_driven = self._driven_weight(pull)
        spare_kg = (w_driven - w_new) / G if math.isfinite(w_new) else math.nan
        carried = self.s.ballast_kg
        ballast_kg = min(spare_kg, carried) if math.isfinite(carried) else math.nan
        e = {**ev, "target_slip": s_t, "target": "s*", "pull_n": pull, "rho_s": rep.rho_s, "a": rep.a,
             "eta": rep.eta, "eta_star": rep.eta_star, "weight_n": self.weight_n, "weight_driven_n": w_driven,
             "weight_needed_n": w_new,
             "weight_spare_kg": spare_kg, "ballast_carried_kg": carried}
        if math.isfinite(ballast_kg) and ballast_kg > 0:
            rest = (f"; the machine stays {spare_kg - ballast_kg:.0f} kg heavier than this pull needs"
                    if spare_kg > carried else "")
            txt = f"Remove about {ballast_kg:.0f} kg of the {carried:.0f} kg of ballast carried{rest}: {why}."
        elif math.isfinite(carried):
            txt = f"No ballast to remove (none declared carried): {why}."
        elif math.isfinite(spare_kg) and spare_kg > 0:
            # the carried ballast is not declared: no amount to take off (from a light pull the formula asked
            # a 7.2 t tractor to shed 4.2–6.5 t), only what the pull needs against what the machine weighs
            txt = (f"Remove ballast if any is carried: this pull needs about {w_new / G:.0f} kg on the driven "
                   f"wheels at s*, they carry {w_driven / G:.0f} kg: {why}.")
        else:
            txt = f"Remove ballast if any is carried: {why}."
        more = (float(curve.mu(s_t)) - rep.rho_s) * w_driven - pull if curve is not None and math.isfinite(
            pull) else math.nan
        # the pull the drivetrain's power allows at this speed: drawbar power = η(s*) × wheel power (eq. 7); from
        # 9.2 kN at 12.6 km/h an 80 kW tractor was told to pull 9.9 kN more, 103 kW at its wheels
        v, power = self._v, self.wheel_power_w
        pull_max = (power * rep.eta_star / v if math.isfinite(power) and math.isfinite(rep.eta_star)
                    and math.isfinite(v) and v > 0.1 else math.nan)
        more_max = pull_max - pull if math.isfinite(pull) else math.nan
        limited = math.isfinite(more) and math.isfinite(more_max) and more_max < more
        if limited:
            more = more_max
        at = f"{power / 1e3:.0f} kW at the wheels at {v * 3.6:.1f} km/h"
        if limited and not more > 0:
            mtxt = (f"Or, in a lower gear, pull more with the same weight, a wider or deeper implement: the "
                    f"{at} are used up: {why}.")
        else:
            # (a higher gear at the same pull leaves the slip, and η(s), where they are: more pull moves them)
            mtxt = ("Or pull more with the same weight, a wider or deeper implement"
                    + (f": about {more / 1e3:.1f} kN more draft" if math.isfinite(more) and more > 0 else "")
                    + (f", as much as the {at} allow" if limited else "") + f": {why}.")
        return [Recommendation("remove_ballast", txt, why, {**e, "ballast_kg": ballast_kg}),
                Recommendation("more_pull", mtxt, why, {**e, "draft_to_add_n": more, "wheel_power_w": power,
                                                        "speed_mps": v, "pull_power_limit_n": pull_max})]
