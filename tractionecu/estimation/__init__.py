"""Traction parameter identification (paper section 3): the AUKF-FS and the curve parameter ``a``.

==============  =================================================================
``config``      :class:`EstimatorConfig`: filter tuning, ``[estimator]`` TOML
``ukf``         unscented filter: sigma points, predict, gated update
``_kernels``    the compiled (numba) core of the filter and of RK4
``supervisor``  covariance matching and the fuzzy supervisor (eqs. 16–17)
``curve``       ``a`` and the surface class from (μ̂, ŝ) pairs (eq. 18)
``estimator``   :class:`Estimator`: ``step(t, inputs, measurements) -> Estimate``
==============  =================================================================

Equation numbers are those of the paper's source (Kobelski et al. 2020), in
order: (11) discrete model x_k = f(x_{k−1}, u_{k−1}) + q, y_k = h(x_k) + r;
(12) predicted distribution; (13) a-priori covariance; (14) mean update;
(15) covariance update; (16) adaptation argmin over A_k; (17) windowed
innovation covariance S̄_k; (18) μ(s).  Earlier project notes call
(16)–(17) "eqs. 12–13", and ``model/mucurve.py`` and README call (18) "eq. 14".
"""
