"""What the driver gets from the estimates: traction efficiency, the optimal slip and advice.

* :mod:`.efficiency`: η(s) from the identified μ(s) curve and ρ_s (paper eq. 7),
  the slip s* that maximises it with its interval, the efficiency lost at the
  current operating point and the pull available at s*;
* :mod:`.rules`: recommendations (ballast, tyre pressure, depth or gear), each
  with the numbers it rests on.  The service never acts on the machine.
"""
