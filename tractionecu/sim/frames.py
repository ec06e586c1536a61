"""Who sends what on the simulated machine's bus: the source addresses of its ECUs and the ISO 11783-7
direction codes, shared by both recording writers (:mod:`.writer`, :mod:`.physwriter`)."""

DRIVETRAIN_SA = 0x80
"""Source address of the drive-train ECU sending wheel speeds, torques and axle load."""
HITCH_SA = 0x82
"""Source address of the rear hitch ECU (ISO 11783-7 hitch status, draft)."""
NAV_SA = 0x1C
"""Source address of the navigation/GNSS ECU sending GBSD."""
TRACTOR_SA = 0x00
"""Source address of the tractor ECU sending WBSD."""
FORWARD, REVERSE = 1, 0
"""WheelBasedMachineDirection (SPN 1864) / GroundBasedMachineDirection (SPN 1861): ISO 11783-7 values
(``dbc/tractionecu.dbc`` VAL_: 0 Reverse, 1 Forward, 2 Error, 3 NotAvailable)."""
