"""The in-cab service: ``tractionecu run``.

An asyncio daemon that reads the drive-train signals from CAN (python-can, any
interface by name) and NMEA from a GNSS receiver (pyserial), steps the same
:class:`~tractionecu.estimation.estimator.Estimator` as ``tractionecu replay``
on a fixed 100 Hz grid, broadcasts μ, slip, ρ_s, a and the status on the bus
after a J1939 address claim, writes map tiles and speaks systemd's notify
protocol.

Modules, in data-flow order:

=================  ============================================================
``config``         TOML configuration, frozen dataclasses, validated
``clock``          service time: epoch seconds advanced by the monotonic clock
``canlink``        python-can bus with its own supervised receive loop
``gps``            NMEA serial reader: strict parse, epochs, gating, reopen
``steps``          estimator step arguments exactly as replay builds them
``address_claim``  J1939-81 address claim state machine (no I/O)
``broadcast``      the three estimate frames of the DBC
``mapwriter``      10 Hz accumulation, tile flushes in a worker thread
``notify``         ``sd_notify`` over ``$NOTIFY_SOCKET``
``heap``           GC freeze after start-up, glibc heap trim and mmap threshold
``daemon``         :class:`~.daemon.Service`: start-up, loops, shutdown
``simulate``       ``run --simulate``: a recording played onto a virtual bus and a pty
=================  ============================================================
"""
