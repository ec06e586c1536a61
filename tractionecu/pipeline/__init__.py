"""One pipeline from bus and GNSS samples to estimates, shared by replay, the service and diagnosis.

=============  ==================================================================
``signals``    the signal table: bus signal -> estimator input or measurement
``gnss``       the one GNSS gating rule (validity, fix quality, HDOP, repeats, age)
``steps``      the step grid and the step rule, vectorised and incremental
``replay``     the replay engine: a recording through the estimator, in memory
               or into a run directory (``estimates.csv``, ``config.toml``, map)
=============  ==================================================================

The daemon (:mod:`tractionecu.service`) feeds :class:`~.steps.StepAssembler`
frame by frame; ``tractionecu replay`` and diagnosis call :func:`~.replay.replay`.
Both apply the same gate and the same step rule, so a capture of the bus
replayed offline gives the daemon's estimates.
"""
