"""Physical truth at a cusp (three-point turn): the wheels' yaw follows the path the positions take.

The truth's wheels roll at v (1 ∓ κ w/2) with the steering curvature κ (the path's, smoothed over a
wheelbase), so the body's yaw is ∫ κ v dt; the positions and heading (what the GNSS course reports) are the
plan's.  Both must tell the same turn: a smoothing window across a cusp gave the wheels half the arc's
curvature over half a wheelbase on each side, the part after the cusp in reverse (the opposite yaw), a
disagreement of κ L / 4 = 0.07 rad per three-point turn that the estimator's curvature filter read as a
rear slip difference: 0.006 1/m of curvature on the straight reverse legs.
"""

import numpy as np

from tractionecu.sim import scenarios
from tractionecu.sim.physical import _steering_curvature, simulate_physical


def test_wheel_yaw_matches_heading_across_the_three_point_turn():
    scn = scenarios.get("physical-headland-reverse", seed=0, duration_s=135.0)
    tr = simulate_physical(scn)
    t, v, k = tr.t, tr.v, tr.curvature
    rev = np.flatnonzero(tr.direction < 0)
    assert len(rev) > 1000                               # the first reverse leg is in the window
    i0 = rev[0] - int(round(20.0 / (t[1] - t[0])))       # from the straight pass before the quarter circle
    i1 = rev[-1]                                         # to the end of the 12 m leg back
    yaw = np.sum(0.5 * (k[i0:i1] * v[i0:i1] + k[i0 + 1:i1 + 1] * v[i0 + 1:i1 + 1]) * np.diff(t[i0:i1 + 1]))
    dpsi = np.unwrap(tr.heading[i0:i1 + 1])
    turned = dpsi[-1] - dpsi[0]
    assert abs(turned) > 1.5                             # the whole quarter circle is in it
    # 0.106 rad with the window across the cusp; 0.0054 with it split there (about 5 cm of the arc)
    assert abs(yaw - turned) < 0.01, (yaw, turned)
    # on the straight leg back the wheels roll straight: no curvature once the machine has left the cusp
    leg = rev[np.abs(v[rev]) > 0.5]
    assert len(leg) > 500
    assert np.max(np.abs(k[leg])) < 1e-9


def test_steering_curvature_without_cusp_is_the_plain_smoothing():
    from tractionecu.sim.physical import DS, _path_curvature
    from tractionecu.sim.plan import s_curves
    p = s_curves(0.0, 0.0, 240.0, 3, 12.0, radius=30.0, v_work=2.5, v_turn=1.2)
    nk = int(round(2.5 / DS))
    k = _path_curvature(p)
    plain = np.convolve(np.pad(k, (nk // 2, nk - 1 - nk // 2), mode="edge"), np.ones(nk) / nk, mode="valid")
    assert np.array_equal(_steering_curvature(p, nk), plain)
