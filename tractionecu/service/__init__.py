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
``dispatch``       each received frame and fix to where it belongs, or counted
``fixes``          recent GNSS fixes, looked up by time for the map
``address_claim``  J1939-81 address claim state machine (no I/O)
``broadcast``      the three estimate frames of the DBC
``network``        address claim on the bus, transmit, the estimate broadcast
``loop``           the estimator built, warmed up and stepped on its grid
``mapwriter``      10 Hz accumulation, tile flushes in a worker thread
``status``         rates and the periodic status line
``notify``         ``sd_notify`` over ``$NOTIFY_SOCKET``
``heap``           GC freeze after start-up, glibc heap trim and mmap threshold
``lifecycle``      parts started in one declared order, stopped in reverse
``daemon``         :class:`~.daemon.Service`: the parts composed, their order
=================  ============================================================

The step rule (which samples go into each estimator step), the signal table
and the GNSS gate are shared with ``replay`` in :mod:`tractionecu.pipeline`.
``run --simulate`` (a recording played onto a virtual bus and a pty) is
:mod:`tractionecu.sim.player`: the simulator drives the service, the service
never imports the simulator.
"""
