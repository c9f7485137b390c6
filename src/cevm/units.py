"""Unit conversion factors, defined once: cevm computes in SI (J, s, m/s) and converts
only at its edges (vehicle files, tables, CSV columns)."""

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
