"""The offset between the CAN logger's clock and GNSS time, found from the speeds both see.

A logger without a real-time clock starts near 1970 or at 0; python-can's ASC
and TRC writers keep only a millisecond start time beside relative times;
``candump -tz``/``-td`` are relative.  The CAN frames then do not overlap the
GNSS epochs, or overlap them wrongly.

Method
------
Each speed is cut to its longest stretch without a silence over
:data:`MAX_GAP_S` (at most :data:`MAX_SPAN_S`).  The CAN speed is the ground-based speed (``GroundBasedMachineSpeed``: the
same quantity the receiver measures), else the wheel-based speed
(``WheelBasedMachineSpeed``, ``WheelBasedVehicleSpeed``), else the mean of
``WheelSpeed_*`` (a wheel speed in rad/s is the ground speed over a radius, and
the correlation below does not see a scale).  Both speeds are resampled on their own
:data:`STEP_S` grids starting at their first sample, and the normalised
cross-correlation over every lag that overlaps at least :data:`MIN_OVERLAP` of
the shorter series is computed by FFT (so a gap of decades costs nothing).  The
best lag is then refined on the GNSS epochs themselves: the CAN speed,
interpolated at ``t_gnss − offset``, is correlated with the GNSS speed for
offsets 1 ms apart around the coarse peak, and a parabola through the best
three gives the offset.  Its uncertainty is the time-delay estimator's
standard deviation, ``sqrt((1 − r) / (N · |r''|))`` with ``r`` the peak
correlation, ``r''`` its curvature [1/s²] and ``N`` the GNSS epochs in the
overlap, but never below the refinement step / √12.

The offset is accepted when the peak correlation is at least
:data:`MIN_CORRELATION` and the GNSS speed varies (standard deviation at least
:data:`MIN_SPEED_STD`); otherwise :func:`estimate_offset` says why not.

Accuracy, measured on the simulated 12 s ``paper-straight`` recording with its
CAN times moved to 0 (``tests/recording/test_clock.py``): from the ground-based
speed the offset is found 30 ms early — the delay with which GBSD follows the
receiver's epoch on the bus — with a stated σ of about 1 ms; from the
wheel-based speed or the wheel speeds 0.11 s early, because the wheels run
ahead of the ground speed while slip builds up during an acceleration.  On
the 7-minute ``paper-three-soils`` run (seed 7), whose turns and stops give the
speed more shape than one ramp, the wheel-based speed and the wheel speeds find
it within 3 ms.  Weighting the fit towards low speeds (where slip costs little
in m/s) or high-passing both speeds moved one bias only to create another on
the other recording, so the plain correlation stays.  The stated σ is the
statistical part only; these biases are not in it.

``t_gnss = t_can + offset``: :func:`shift_can` adds the offset to every CAN time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

STEP_S = 0.05
"""Coarse grid step [s] of the FFT correlation."""
FINE_STEP_S = 0.001
"""Step [s] of the refinement on the GNSS epochs."""
MIN_OVERLAP = 0.5
"""Smallest overlap, as a fraction of the shorter series, a lag must give to count."""
MIN_CORRELATION = 0.9
"""Smallest peak correlation accepted."""
MIN_SPEED_STD = 0.1
"""Smallest standard deviation [m/s] of the GNSS speed in the overlap: a constant speed has no timing."""
MAX_GAP_S = 5.0
"""A silence longer than this [s] splits a speed series; the longest stretch is correlated."""
MAX_SPAN_S = 6 * 3600.0
"""At most this much [s] of each series is correlated (a 0.05 s grid of 432 000 points)."""
GOOD_OVERLAP = 0.5
"""A trusted CAN clock whose frames and the GNSS epochs overlap over at least this fraction of the shorter
of the two spans is only checked (:data:`CHECK_MIN_S`)."""
CHECK_MIN_S = 1.0
"""A trusted CAN clock that overlaps the GNSS epochs well is still checked: an offset found beyond this [s]
is the logger's clock set wrong (a clock without time sync runs seconds off) and is applied.  Below it the
times are kept: the GNSS latency and the wheels' lead over the ground speed while slip builds up are tenths
of a second (module doc, "Accuracy"), and a small CAN-to-GNSS skew is the diagnosis's to find
(``clock_skew``), not the reader's to hide."""
CHECK_RMS_RATIO = 2.0
"""... and only when the speeds disagree at the logged times: the RMS of GNSS speed minus CAN speed at zero
offset at least this many times its RMS at the offset found.  A drive that repeats itself (the same pass
driven again and again) correlates as well one repetition away; there the two RMS are alike and the logged
times are kept."""
CHECK_RMS_MIN = 0.1
"""... and at least this [m/s] (a speed error the estimator would feel: 4 % at 2.5 m/s)."""
SPAN_SLACK_S = 2.0
"""... and only when the offset agrees with the spans: a logger whose clock is off by Δ starts and stops Δ
away from the receiver's log, so Δ must lie between the two differences of the spans' starts and ends
(either log may start or stop first), widened by this [s].  An offset the spans contradict is reported and
not applied."""

SPEED_SIGNALS = ("GroundBasedMachineSpeed", "WheelBasedMachineSpeed", "WheelBasedVehicleSpeed")
WHEEL_SIGNALS = ("WheelSpeed_FL", "WheelSpeed_FR", "WheelSpeed_RL", "WheelSpeed_RR")


@dataclass
class ClockOffset:
    """``offset_s`` to add to CAN times to get GNSS time [s] (NaN when not found), its standard deviation
    ``sigma_s`` [s], the peak correlation, the CAN signal used, and why it was not found (``reason``)."""

    offset_s: float
    sigma_s: float
    correlation: float
    signal: str
    reason: str = ""
    contradicted: bool = False
    """The speeds disagree at the logged times but the logs' spans contradict the offset: worth reporting."""

    @property
    def found(self) -> bool:
        return math.isfinite(self.offset_s) and not self.reason

    def describe(self) -> str:
        if self.found:
            return (f"CAN clock offset {self.offset_s:+.3f} s ± {self.sigma_s * 1e3:.1f} ms "
                    f"(correlation {self.correlation:.3f} of {self.signal} with GNSS speed)")
        return f"CAN clock offset not found: {self.reason}"


def overlap_fraction(a0: float, a1: float, b0: float, b1: float) -> float:
    """The overlap of [a0, a1] and [b0, b1] as a fraction of the second (0 when disjoint or degenerate)."""
    if not (b1 > b0) or not all(math.isfinite(x) for x in (a0, a1, b0, b1)):
        return 0.0
    return max(0.0, min(a1, b1) - max(a0, b0)) / (b1 - b0)


def can_speed(signals: Mapping) -> tuple[str, np.ndarray, np.ndarray] | None:
    """(name, t, value) of the CAN speed the offset is found from, or None (module doc)."""
    for name in SPEED_SIGNALS:
        s = signals.get(name)
        if s is not None and np.count_nonzero(np.isfinite(s.value)) >= 10:
            ok = np.isfinite(s.value)
            return name, s.t[ok], s.value[ok]
    wheels = [signals[n] for n in WHEEL_SIGNALS if n in signals and len(signals[n]) >= 10]
    if not wheels:
        return None
    t = wheels[0].t
    v = np.nanmean(np.vstack([np.interp(t, w.t, np.abs(w.value)) for w in wheels]), axis=0)
    ok = np.isfinite(v)
    return "mean wheel speed", t[ok], v[ok]


def _longest_run(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The longest stretch of samples without a silence over :data:`MAX_GAP_S`, cut to :data:`MAX_SPAN_S`:
    no grid is sized from a span that jumps."""
    cuts = np.flatnonzero(np.diff(t) > MAX_GAP_S) + 1
    bounds = np.concatenate([[0], cuts, [t.size]])
    k = int(np.argmax(np.diff(bounds)))
    t, v = t[bounds[k]:bounds[k + 1]], v[bounds[k]:bounds[k + 1]]
    keep = t <= t[0] + MAX_SPAN_S
    return t[keep], v[keep]


def _resample(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    n = int(math.floor((t[-1] - t[0]) / STEP_S)) + 1
    return np.interp(t[0] + np.arange(n) * STEP_S, t, v)


def _ncc(a: np.ndarray, b: np.ndarray, min_n: int) -> np.ndarray:
    """Normalised cross-correlation of ``a`` with ``b`` for every lag k (b[j] against a[j + k]),
    k from −(len(b) − 1) to len(a) − 1; NaN where fewer than ``min_n`` samples overlap."""
    na, nb = a.size, b.size
    n = 1 << int(math.ceil(math.log2(na + nb)))

    def xc(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        r = np.fft.irfft(np.fft.rfft(x, n) * np.conj(np.fft.rfft(y, n)), n)
        return np.concatenate([r[n - (nb - 1):], r[:na]])

    ones_a, ones_b = np.ones(na), np.ones(nb)
    cnt = np.rint(xc(ones_a, ones_b))
    sa, sb = xc(a, ones_b), xc(ones_a, b)
    saa, sbb = xc(a * a, ones_b), xc(ones_a, b * b)
    sab = xc(a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = sab - sa * sb / cnt
        va = saa - sa * sa / cnt
        vb = sbb - sb * sb / cnt
        r = cov / np.sqrt(va * vb)
    r[(cnt < min_n) | ~(va > 1e-9 * cnt) | ~(vb > 1e-9 * cnt)] = np.nan
    return r


FINE_CHUNK = 1 << 18
"""Interpolated samples per pass of :func:`_corr_many`: its arrays hold at most this many floats each (2 MiB),
whatever the recording's length."""


def _corr_many(ct: np.ndarray, cv: np.ndarray, gt: np.ndarray, gv: np.ndarray,
               offs: np.ndarray) -> np.ndarray:
    """The correlation of the GNSS speed ``gv`` at its epochs ``gt`` with the CAN speed ``cv`` interpolated at
    ``gt − offset`` where that lies within the CAN times ``ct``, for every offset of ``offs``; NaN where fewer than
    5 epochs overlap or either speed is constant there.  The offsets go in passes of at most :data:`FINE_CHUNK`
    interpolated samples: one interpolation per pass, not one call per offset."""
    out = np.full(offs.size, np.nan)
    per = max(1, FINE_CHUNK // max(gt.size, 1))
    for a in range(0, offs.size, per):
        o = offs[a:a + per]
        tc = gt[None, :] - o[:, None]
        m = (tc >= ct[0]) & (tc <= ct[-1])
        n = m.sum(axis=1)
        x = np.interp(tc, ct, cv)
        x[~m] = 0.0
        y = np.where(m, gv[None, :], 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            dx = np.where(m, x - (x.sum(axis=1) / n)[:, None], 0.0)
            dy = np.where(m, y - (y.sum(axis=1) / n)[:, None], 0.0)
            sxx, syy = (dx * dx).sum(axis=1), (dy * dy).sum(axis=1)
            r = (dx * dy).sum(axis=1) / np.sqrt(sxx * syy)
        r[(n < 5) | ~(sxx > 0.0) | ~(syy > 0.0)] = np.nan
        out[a:a + per] = r
    return out


def estimate_offset(signals: Mapping, gps_t: np.ndarray, gps_speed: np.ndarray) -> ClockOffset:
    """The offset from the CAN clock to GNSS time (module doc); ``reason`` says why when not found."""
    src = can_speed(signals)
    if src is None:
        return ClockOffset(math.nan, math.nan, math.nan, "", "no wheel-based speed or wheel speeds on the bus")
    name, ct, cv = src
    ok = np.isfinite(gps_speed) & np.isfinite(gps_t)
    if ok.sum() < 10:
        return ClockOffset(math.nan, math.nan, math.nan, name, "fewer than 10 GNSS epochs with a speed")
    ct, cv = _longest_run(ct, cv)
    gt, gv = _longest_run(gps_t[ok], gps_speed[ok])
    if gt.size < 10:
        return ClockOffset(math.nan, math.nan, math.nan, name, "fewer than 10 GNSS epochs with a speed")
    if ct[-1] - ct[0] < 10 * STEP_S or gt[-1] - gt[0] < 10 * STEP_S:
        return ClockOffset(math.nan, math.nan, math.nan, name, "CAN or GNSS speed spans less than 0.5 s")
    a, b = _resample(ct, cv), _resample(gt, gv)
    min_n = max(5, int(MIN_OVERLAP * min(a.size, b.size)))
    r = _ncc(a, b, min_n)
    if not np.isfinite(r).any():
        return ClockOffset(math.nan, math.nan, math.nan, name, "the speeds are constant: nothing to correlate")
    k = int(np.nanargmax(r)) - (b.size - 1)           # b[j] matches a[j + k]
    coarse = float(gt[0] - (ct[0] + k * STEP_S))
    offs = coarse + np.arange(-2 * STEP_S, 2 * STEP_S + FINE_STEP_S / 2, FINE_STEP_S)
    rs = _corr_many(ct, cv, gt, gv, offs)
    if not np.isfinite(rs).any():
        return ClockOffset(math.nan, math.nan, math.nan, name, "the speeds do not overlap at the best lag")
    i = int(np.nanargmax(rs))
    off, rmax = float(offs[i]), float(rs[i])
    curv = math.nan
    if 0 < i < rs.size - 1 and np.isfinite(rs[i - 1:i + 2]).all():
        y0, y1, y2 = rs[i - 1:i + 2]
        den = y0 - 2 * y1 + y2
        if den < 0:
            off += FINE_STEP_S * 0.5 * (y0 - y2) / den
            curv = den / FINE_STEP_S ** 2
    tc = gt - off
    inside = (tc >= ct[0]) & (tc <= ct[-1])             # the GNSS epochs the CAN speed overlaps at the offset
    n = int(inside.sum())
    speed_std = float(gv[inside].std()) if n else 0.0
    floor = FINE_STEP_S / math.sqrt(12.0)
    sigma = math.sqrt(max(1.0 - rmax, 0.0) / (n * -curv)) if curv < 0 and n else math.inf
    sigma = max(sigma, floor)
    reason = ""
    if speed_std < MIN_SPEED_STD:
        reason = (f"the GNSS speed hardly varies where the two overlap (std {speed_std:.2f} m/s < "
                  f"{MIN_SPEED_STD} m/s): a constant speed has no timing")
    elif rmax < MIN_CORRELATION:
        reason = (f"{name} and the GNSS speed correlate at most {rmax:.2f} (< {MIN_CORRELATION}); "
                  "the recording may not show the same drive")
    return ClockOffset(off if not reason else math.nan, sigma, rmax, name, reason)


def check_offset(signals: Mapping, gps_t: np.ndarray, gps_speed: np.ndarray,
                 can_span: tuple[float, float] | None = None) -> ClockOffset:
    """The offset of a trusted clock whose frames overlap the GNSS epochs.  Found only when it is beyond
    :data:`CHECK_MIN_S`, the speeds disagree at the logged times (:data:`CHECK_RMS_RATIO`,
    :data:`CHECK_RMS_MIN`) and, given ``can_span`` (the first and last CAN frame [s]), it agrees with the
    logs' spans (:data:`SPAN_SLACK_S`); otherwise ``reason`` says why the logged times stand
    (``contradicted`` when the speeds disagree but the spans contradict the offset)."""
    off = estimate_offset(signals, gps_t, gps_speed)
    if not off.found:
        return off
    if abs(off.offset_s) <= CHECK_MIN_S:
        return ClockOffset(math.nan, off.sigma_s, off.correlation, off.signal,
                           f"offset {off.offset_s:+.3f} s is within {CHECK_MIN_S:g} s")
    ok = np.isfinite(gps_speed) & np.isfinite(gps_t)
    src = can_speed(signals)
    ct, cv = _longest_run(src[1], src[2])
    gt, gv = _longest_run(gps_t[ok], gps_speed[ok])
    # the CAN speed's scale (wheel speeds in rad/s) fitted at each offset, so that only the timing counts
    def rms(o: float) -> float:
        tc = gt - o
        m = (tc >= ct[0]) & (tc <= ct[-1])
        if m.sum() < 5:
            return math.nan
        x = np.interp(tc[m], ct, cv)
        k = float(x @ gv[m] / (x @ x)) if x @ x > 0 else 1.0
        return float(np.sqrt(np.mean((k * x - gv[m]) ** 2)))
    r0, r1 = rms(0.0), rms(off.offset_s)
    if not (r0 >= max(CHECK_RMS_RATIO * r1, CHECK_RMS_MIN)):
        return ClockOffset(math.nan, off.sigma_s, off.correlation, off.signal,
                           f"the speeds agree at the logged times (RMS {r0:.3f} m/s; {r1:.3f} m/s "
                           f"{off.offset_s:+.3f} s away)")
    if can_span is not None:
        d0, d1 = float(gps_t[ok][0] - can_span[0]), float(gps_t[ok][-1] - can_span[1])
        lo, hi = min(d0, d1) - SPAN_SLACK_S, max(d0, d1) + SPAN_SLACK_S
        if not lo <= off.offset_s <= hi:
            return ClockOffset(math.nan, off.sigma_s, off.correlation, off.signal,
                               f"the speeds agree best {off.offset_s:+.3f} s away, but the logs' starts and ends "
                               f"differ by {d0:+.1f} s and {d1:+.1f} s: not applied; check the logger's clock",
                               contradicted=True)
    return off


def shift_can(signals: Mapping, stats, offset: float) -> None:
    """Add ``offset`` [s] to every CAN time: series, first/last frame, per-message spans and gaps,
    address claims."""
    for s in signals.values():
        s.t = s.t + offset
    stats.can_t_first += offset
    stats.can_t_last += offset
    for ms in stats.messages.values():
        ms.t_first += offset
        ms.t_last += offset
        ms.gaps = [(t + offset, dt) for t, dt in ms.gaps]
    for c in stats.address_claims:
        c.t_first += offset
