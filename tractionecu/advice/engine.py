"""One object the service and the replay feed with estimates: efficiency, optimum and advice.

:class:`AdviceEngine` takes estimates at about 10 Hz (:meth:`feed`); the
optimum s* and its interval are recomputed every ``optimum_period_s``
(about 1 s of work per minute of run), the rest of the time the last one is
reused.  It logs each new or withdrawn recommendation once (the journal).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from .efficiency import FLAGS, S_STAR_BITS, EfficiencyConfig, EfficiencyReport, EfficiencyTracker, curve_of, efficiency_config_for
from .rules import AdviceSettings, Advisor, Recommendation

log = logging.getLogger(__name__)


class AdviceEngine:
    """Efficiency tracker + advisor (module doc)."""

    def __init__(self, vehicle: Any = None, settings: AdviceSettings | None = None, *,
                 optimum_period_s: float = 1.0, eff: EfficiencyConfig | None = None) -> None:
        if eff is None:
            eff = efficiency_config_for(vehicle) if vehicle is not None else EfficiencyConfig()
        self.tracker = EfficiencyTracker(eff)
        settings = settings or AdviceSettings()
        if vehicle is not None and math.isnan(settings.tyre_pressure_pa):
            from dataclasses import replace
            settings = replace(settings, tyre_pressure_pa=float(vehicle.tyre_pressure_pa))
        power = (float(vehicle.rated_power_w) * float(vehicle.drivetrain.efficiency) if vehicle is not None
                 else math.nan)
        self.advisor = Advisor(settings, weight_n=eff.weight_n, front_fraction=eff.front_fraction,
                               wheelbase_m=eff.wheelbase_m, hitch_height_m=eff.hitch_height_m, wheel_power_w=power)
        self.optimum_period_s = optimum_period_s
        self._t_opt = -math.inf
        self.report: EfficiencyReport | None = None
        self.advice: list[Recommendation] = []
        self.fed = 0

    def feed(self, est: Any) -> EfficiencyReport:
        """Add one estimate; returns the efficiency report (``self.advice`` holds the advice)."""
        t = float(getattr(est, "t", math.nan))
        opt = not (t - self._t_opt < self.optimum_period_s)
        if opt:
            self._t_opt = t
        rep = self.tracker.update(est, with_optimum=opt)
        s = np.asarray(getattr(est, "slip", [math.nan] * 4), dtype=float)
        axles = (float(np.mean(s[:2])), float(np.mean(s[2:])))
        before = {r.kind for r in self.advice}
        self.advice = self.advisor.update(rep, float(getattr(est, "v", math.nan)), curve_of(est), axles,
                                          front_driven=getattr(est, "front_engaged", True) is not False)
        after = {r.kind for r in self.advice}
        for r in self.advice:
            if r.kind not in before:
                log.warning("advice: %s", r.text)
        for k in sorted(before - after):
            log.info("advice withdrawn: %s", k)
        self.report = rep
        self.fed += 1
        return rep

    def status_text(self) -> str:
        """Short text for the status line."""
        r = self.report
        if r is None:
            return "eta -"
        eta = "-" if not math.isfinite(r.eta) else f"{r.eta:.3f}"
        if r.s_star_valid:
            opt = f"s* {r.s_star:.3f} [{r.s_star_lo:.3f}, {r.s_star_hi:.3f}] eta* {r.eta_star:.3f}"
        else:
            opt = "s* - (" + ", ".join(FLAGS[b] for b in FLAGS if b & r.flags & S_STAR_BITS) + ")"
        adv = f"  advice: {', '.join(a.kind for a in self.advice)}" if self.advice else ""
        return f"eta {eta}  {opt}{adv}"
