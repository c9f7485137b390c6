"""Unit conversion factors, defined once: cevm computes in SI (J, s, m/s, kg, m) and
converts only at its edges (vehicle files, logger columns, tables, CSV columns).

Names say the direction: ``A_PER_B`` is how many A make one B, and ``X_TO_Y``
multiplies a value in X to give it in Y (so divides a value in Y to give it in X).
Each factor is written the one way the code has always computed it, so outputs stay
the same to the bit (``KMH_TO_MPS`` is ``1 / 3.6``; dividing by ``MPS_TO_KMH`` is
dividing by 3.6).
"""

import math

#: Joules per kilowatt-hour.
J_PER_KWH = 3.6e6
#: Joules per watt-hour.
J_PER_WH = 3600.0
#: Joules per megajoule.
J_PER_MJ = 1.0e6
#: Watts per kilowatt.
W_PER_KW = 1.0e3
#: Seconds per hour.
S_PER_H = 3600.0
#: Metres per second per km/h.
KMH_TO_MPS = 1.0 / 3.6
#: km/h per metre per second.
MPS_TO_KMH = 3.6
#: Metres per second per mile per hour (international mile, 1609.344 m).
MPH_TO_MPS = 0.44704
#: Metres per second per knot (1,852 m per hour).
KNOT_TO_MPS = 1852.0 / 3600.0
#: Metres per international mile.
M_PER_MILE = 1609.344
#: Metres per foot (international foot).
FT_TO_M = 0.3048
#: Radians per second per revolution per minute.
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
#: Cubic metres per litre.
M3_PER_L = 1.0e-3
#: Litres per US gallon.
L_PER_GAL_US = 3.785411784
#: Litres per imperial gallon.
L_PER_GAL_IMP = 4.54609
#: Kilograms per pound (avoirdupois).
KG_PER_LB = 0.45359237
#: Pascals per bar.
PA_PER_BAR = 1.0e5
