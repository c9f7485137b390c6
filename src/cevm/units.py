"""Unit conversion factors, defined once: cevm computes in SI (J, s, m/s) and converts
only at its edges (vehicle files, tables, CSV columns)."""

import math

#: Joules per kilowatt-hour.
J_PER_KWH = 3.6e6
#: Joules per megajoule.
J_PER_MJ = 1.0e6
#: Seconds per hour.
S_PER_H = 3600.0
#: Metres per second per km/h.
KMH_TO_MPS = 1.0 / 3.6
#: Metres per second per mile per hour (international mile, 1609.344 m).
MPH_TO_MPS = 0.44704
#: Metres per foot (international foot).
FT_TO_M = 0.3048
#: Watts per kilowatt.
W_PER_KW = 1.0e3
#: Radians per second per revolution per minute.
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
#: Cubic metres per litre.
M3_PER_L = 1.0e-3
#: Pascals per bar.
PA_PER_BAR = 1.0e5
